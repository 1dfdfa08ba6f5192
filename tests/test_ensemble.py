"""The regional ensemble (issue 25): its partition, the routing by the goal's cell (acting,
replay, normaliser), the budget shared with one agent's, resume, and learning the toy env."""

import json

import numpy as np
import pytest
import torch
import toy_goal_env
from scipy.cluster.vq import kmeans as scipy_kmeans
from test_ddpg_train import TASK, TINY, eval_table, train

from ddpg_her.agent import DDPG
from ddpg_her.agents import make_agent
from ddpg_her.buffer import Layout
from ddpg_her.config import AgentConfig
from ddpg_her.ensemble import CellBuffer, Ensemble, task_goals, task_partitions
from ddpg_her.runfolder import RunFolder
from ddpg_her.trainer import Trainer
from regions.partition import KMeansSettings, Partition, fit_partition, nearest_cell

OBS, GOAL, ACT = 6, 2, 2
IN = OBS + 2 * GOAL
HALVES = Partition(np.array([[-0.5, 0.0], [0.5, 0.0]]))
"""Two cells of the toy plane: x < 0 and x > 0."""


def ensemble_config(**kw) -> AgentConfig:
    return AgentConfig(**{**TINY.to_dict(), "ensemble": 2, **kw})


# --- the partition ------------------------------------------------------------------------------
def test_partition_is_deterministic_covers_the_goals_and_is_a_kmeans_fixed_point():
    goals = task_goals(toy_goal_env.ENV_ID, TASK, 2000, seed=5)
    a, b = fit_partition(goals, 4), fit_partition(goals, 4)
    assert np.array_equal(a.centres, b.centres)  # same seed, same partition
    assert np.array_equal(task_goals(toy_goal_env.ENV_ID, TASK, 2000, seed=5), goals)
    cell = a.cell(goals)
    # every goal in exactly one cell, its nearest centre (checked by a plain loop)
    brute = [int(np.argmin([np.linalg.norm(g - c) for c in a.centres])) for g in goals[:200]]
    assert cell[:200].tolist() == brute
    counts = np.bincount(cell, minlength=4)
    assert counts.min() > 0.15 * len(goals)  # no empty cell; about equal shares of the goals
    # Lloyd's fixed point: each centre is the mean of its cell's goals
    for i in range(4):
        assert np.allclose(a.centres[i], goals[cell == i].mean(0), atol=1e-12)
    # as good as an independent k-means (scipy's, best of 10 starts) to 1 %
    _, scipy_distortion = scipy_kmeans(goals, 4, iter=50, seed=np.random.default_rng(0))
    ours = np.mean(np.linalg.norm(goals - a.centres[cell], axis=1))
    assert ours <= 1.01 * scipy_distortion
    # another seed, another start: the same cells up to rounding on this convex square
    c = fit_partition(goals, 4, KMeansSettings(seed=7))
    assert np.allclose(c.centres, a.centres, atol=0.05)


def test_kmeans_refills_an_empty_cell_and_refuses_too_few_goals():
    # two far clusters and three cells: a start with two centres in one cluster must still
    # end with every cell holding goals
    rng = np.random.default_rng(0)
    goals = np.concatenate([rng.normal(0.0, 0.01, (50, 2)), rng.normal(5.0, 0.01, (50, 2))])
    for seed in range(20):
        p = fit_partition(goals, 3, KMeansSettings(seed=seed))
        assert np.bincount(p.cell(goals), minlength=3).min() > 0
    with pytest.raises(ValueError, match="at least 3 distinct goals"):
        fit_partition(np.zeros((10, 2)), 3)


def test_ur5_partitions_are_shared_by_the_seeds_of_a_task_and_recorded(tmp_path):
    import envs  # noqa: F401  (registers UR5Reach-v0)

    task = {"region": "farbox", "n_joints": 3}
    small = KMeansSettings(goals=200)
    parts = task_partitions("UR5Reach-v0", [task, task, {**task, "region": "zheight"}], 4, small)
    assert parts[0] is parts[1] and not np.allclose(parts[0].centres, parts[2].centres)
    assert all(p.centres.shape == (4, 3) for p in parts)
    # the far box's centres lie in the far box (x in [0.5, 0.9] m, |y| <= 0.4 m, z <= 0.4 m)
    c = parts[0].centres
    assert (c[:, 0] > 0.5).all() and (c[:, 0] < 0.9).all() and (abs(c[:, 1]) < 0.4).all()


# --- routing --------------------------------------------------------------------------------------
def inputs(goals: np.ndarray, rng: np.random.Generator) -> torch.Tensor:
    """Network inputs (K, n, IN) with the given desired goals (K, n, GOAL) in their last entries."""
    k, n = goals.shape[:2]
    x = rng.normal(size=(k, n, IN))
    x[..., -GOAL:] = goals
    return torch.as_tensor(x)


def two_seed_ensemble(config: AgentConfig, partitions=(HALVES, HALVES)) -> Ensemble:
    return make_agent(config, IN, ACT, dtype=torch.float64, partitions=list(partitions),
                      init_generators=[torch.Generator().manual_seed(s) for s in (1, 2)])


@pytest.mark.parametrize("algo", ["ddpg", "td3", "sac"])
def test_the_goals_cell_picks_the_member_that_acts(algo):
    config = ensemble_config(algo=algo)
    agent = two_seed_ensemble(config, (HALVES, Partition(np.array([[0.0, -0.5], [0.0, 0.5]]))))
    rng = np.random.default_rng(0)
    goals = rng.uniform(-1, 1, (2, 9, GOAL))
    x = inputs(goals, rng)
    for k in range(2):
        agent.members.normalizer.update(2 * k + 1, rng.normal(size=(5, IN)))  # not all alike
    got = agent.act(x)
    # the reference: each row alone, by the member a plain loop says owns its goal
    part = [HALVES, agent.partitions[1]]
    for k in range(2):
        for i in range(9):
            owner = int(np.argmin([np.linalg.norm(goals[k, i] - c) for c in part[k].centres]))
            alone = torch.zeros(4, 1, IN, dtype=torch.float64)
            alone[2 * k + owner] = x[k, i]
            want = agent.members.act(alone)[2 * k + owner, 0]
            assert torch.allclose(got[k, i], want, atol=1e-12), (k, i, owner)
            others = agent.members.act(alone)[2 * k + 1 - owner, 0]
            assert not torch.allclose(want, others)  # members differ: routing is visible


def test_replay_files_each_transition_under_its_goals_cell_and_members_sample_only_it():
    """Real and relabelled rows alike go to the cell of their own desired goal, also when the
    ring buffer wraps around; a restore from chunks files them as the appends did."""
    layout = Layout(IN, ACT)
    centres = torch.as_tensor(np.stack([HALVES.centres, HALVES.centres]))
    buf = CellBuffer(2, 50, layout, centres, dtype=torch.float64, device="cpu")
    rng = np.random.default_rng(1)
    written = [[], []]
    for _ in range(9):  # 9 episodes of 3..12 rows each: wraps the 50-row ring
        for k in range(2):
            rows = rng.normal(size=(rng.integers(3, 13), layout.width))
            buf.add(k, rows)
            written[k].append(rows)
    for k in range(2):
        rows = np.concatenate(written[k])[-50:]
        first = len(np.concatenate(written[k])) - 50
        cell = HALVES.cell(rows[:, IN - GOAL:IN])
        for c in range(2):
            q = buf._queues[k][c]
            assert q.data[q.head:q.tail].tolist() == (first + np.flatnonzero(cell == c)).tolist()
    gens = [torch.Generator().manual_seed(s) for s in (3, 4)]
    x = buf.sample(16, gens)[0]
    assert x.shape == (4, 16, IN)
    for member in range(4):
        assert (HALVES.cell(x[member, :, -GOAL:].numpy()) == member % 2).all()
    # a restore: the stored window put back as two chunks gives the same draws
    other = CellBuffer(2, 50, layout, centres, dtype=torch.float64, device="cpu")
    for k in range(2):
        start, rows = buf.since(k, 0)
        other.put(k, start, rows[:20])
        other.put(k, start + 20, rows[20:])
    gens2 = [torch.Generator().manual_seed(s) for s in (3, 4)]
    for g in gens:
        g.manual_seed(5)
    for g in gens2:
        g.manual_seed(5)
    for a, b in zip(buf.sample(16, gens), other.sample(16, gens2), strict=True):
        assert torch.equal(a, b)


@pytest.mark.parametrize("device", [
    "cpu", pytest.param("cuda", marks=[pytest.mark.gpu, pytest.mark.skipif(
        not torch.cuda.is_available(), reason="needs a CUDA device")])])
def test_replay_files_tensor_rows_as_it_files_the_same_rows_as_arrays(device):
    """The torch env backend hands the buffer tensors on the training device: they are filed
    under the same cells as the same rows given as a host array (a CUDA tensor once went
    through numpy, which cannot read device memory)."""
    layout = Layout(IN, ACT)
    centres = torch.as_tensor(np.stack([HALVES.centres, HALVES.centres]))
    host = CellBuffer(2, 50, layout, centres, dtype=torch.float64, device=device)
    dev = CellBuffer(2, 50, layout, centres, dtype=torch.float64, device=device)
    rng = np.random.default_rng(4)
    for _ in range(7):
        for k in range(2):
            rows = rng.normal(size=(rng.integers(3, 13), layout.width))
            host.add(k, rows)
            dev.add(k, torch.as_tensor(rows, device=device))
    for k in range(2):
        for a, b in zip(host._queues[k], dev._queues[k], strict=True):
            assert a.data[a.head:a.tail].tolist() == b.data[b.head:b.tail].tolist()
            assert a.tail > a.head


def test_the_normaliser_statistics_are_per_member_of_the_rows_routed_to_it():
    agent = two_seed_ensemble(ensemble_config())
    rng = np.random.default_rng(2)
    x = inputs(rng.uniform(-1, 1, (1, 40, GOAL)), rng)[0].numpy()
    agent.normalizer.update(1, x)
    cell = HALVES.cell(x[:, -GOAL:])
    norm = agent.members.normalizer
    assert norm.count.tolist() == [0, 0, (cell == 0).sum(), (cell == 1).sum()]
    assert np.allclose(norm.sum[3], x[cell == 1].sum(0))
    agent.normalizer.update(0, torch.as_tensor(x))  # the torch backend's tensors too
    assert np.allclose(norm.sum[0], x[cell == 0].sum(0))


# --- the budget ---------------------------------------------------------------------------------
def counted_updates(tmp_path, config: AgentConfig, monkeypatch) -> tuple[int, list[int], list]:
    """Member-updates per seed, minibatch sizes, and eval rows of a 2-seed run."""
    counts = []
    original = DDPG.update

    def counting(self, x, *rest):
        counts.append((x.shape[0], x.shape[1]))
        return original(self, x, *rest)

    monkeypatch.setattr(DDPG, "update", counting)
    rows = train([tmp_path / "s0", tmp_path / "s1"], seeds=[0, 1], config=config)
    monkeypatch.setattr(DDPG, "update", original)
    stacked = {n for n, _ in counts}
    assert len(stacked) == 1
    per_seed = len(counts) * stacked.pop() // 2
    return per_seed, sorted({b for _, b in counts}), rows


def test_the_members_share_one_agents_updates_and_environment_steps(tmp_path, monkeypatch):
    plain = AgentConfig(**{**TINY.to_dict(), "updates_per_episode": 8})
    single, batch1, rows1 = counted_updates(tmp_path / "one", plain, monkeypatch)
    ens = AgentConfig(**{**plain.to_dict(), "ensemble": 4})
    members, batch4, rows4 = counted_updates(tmp_path / "four", ens, monkeypatch)
    learning = TINY.episodes - TINY.warmup_episodes
    assert single == members == learning * 8  # 8 updates per episode in all, 2 per member
    assert batch1 == batch4 == [TINY.batch_size]
    # equal environment steps: one episode per seed per training episode, whichever acts
    assert [r["episode"] for r in rows1[0]] == [r["episode"] for r in rows4[0]]


# --- run folders and resume ---------------------------------------------------------------------
class Crash(Exception):
    pass


@pytest.mark.parametrize("algo", ["ddpg", "sac"])
def test_an_ensemble_run_resumes_to_the_uninterrupted_eval_csv(tmp_path, monkeypatch, algo):
    """SAC too: its members sample their actions, so every member's generator must resume."""
    config = ensemble_config(algo=algo)
    train([tmp_path / "whole"], config=config)
    original = Trainer.train_episode

    def crashing(self):
        if self.episode == 7:
            raise Crash
        return original(self)

    monkeypatch.setattr(Trainer, "train_episode", crashing)
    with pytest.raises(Crash):
        train([tmp_path / "cut"], config=config)
    monkeypatch.setattr(Trainer, "train_episode", original)
    train([tmp_path / "cut"], config=config, resume=True)
    assert eval_table(tmp_path / "cut") == eval_table(tmp_path / "whole")
    a, b = (RunFolder(tmp_path / d).load_checkpoint(12)["agent"] for d in ("whole", "cut"))
    assert len(a["ensemble"]) == 2
    for m, n in zip(a["ensemble"], b["ensemble"], strict=True):
        for key in m["actor"]:
            assert torch.equal(m["actor"][key], n["actor"][key])
    spec = json.loads((tmp_path / "whole" / "spec.json").read_text())
    assert spec["agent"]["ensemble"] == 2 and spec["partition"]["cells"] == 2
    assert np.array(spec["partition"]["centres"]).shape == (2, GOAL)
    # another M is another agent
    with pytest.raises(ValueError, match=r"agent\.ensemble \(was 2, now 4\)"):
        train([tmp_path / "whole"], config=ensemble_config(ensemble=4, episodes=15),
              resume=True)


def test_k_stacked_ensembles_train_as_they_would_alone(tmp_path):
    config = ensemble_config()
    train([tmp_path / "k2-s1", tmp_path / "k2-s2"], seeds=[1, 2], config=config)
    train([tmp_path / "k1-s2"], seeds=[2], config=config)
    assert eval_table(tmp_path / "k2-s2") == eval_table(tmp_path / "k1-s2")


# --- learning -------------------------------------------------------------------------------------
def test_an_ensemble_of_ddpg_learns_the_toy_task(tmp_path):
    """Two members on the halves of the toy plane, each making the 40 updates per episode of
    DDPG's toy test (80 in all), learn it, though slower than one agent (each member sees half
    of the episodes); judged over six seeds trained as one stack, since one seed's curve depends
    on the CPU's rounding (seed 0 at episode 40: 7 successes on one machine, 13 on another).
    Measured on the development machine (240 episodes), each seed's mean over its last three
    sessions: 20, 20, 22.3, 12.3, 24.7, 24.3 of 30 (mean 20.6); the first session 0 or 1."""
    config = AgentConfig(episodes=240, eval_every=10, eval_episodes=30, hidden_sizes=(64, 64),
                         updates_per_episode=80, actor_lr=1e-3, tau=0.05,
                         exploration="epsilon", exploration_rate=0.3, warmup_episodes=0,
                         ensemble=2)
    seeds = range(6)
    runs = train([tmp_path / f"ens-s{s}" for s in seeds], seeds=seeds, config=config)
    hits = np.array([[r["successes"] for r in rows] for rows in runs])  # (seed, session)
    assert hits[:, 0].mean() <= 3, hits
    assert hits[:, -3:].mean() >= 14, hits
    first, last = (np.mean([rows[i]["mean_final_distance_m"] for rows in runs]) for i in (0, -1))
    assert last < 0.5 * first, (first, last)


def test_nearest_cell_of_the_partition_module_and_the_agents_routing_agree():
    """The numpy cell (regions.partition) and the torch one (the agent's routing) are one rule."""
    agent = two_seed_ensemble(ensemble_config())
    rng = np.random.default_rng(3)
    goals = rng.uniform(-1, 1, (2, 200, GOAL)).astype(np.float32)
    assert np.array_equal(agent.cells(inputs(goals, rng)).numpy(),
                          nearest_cell(goals, HALVES.centres))


def test_a_loaded_ensemble_policy_acts_as_the_trained_ensemble(tmp_path):
    """`ddpg_her.load` of an ensemble run routes each goal to its member as the trainer did."""
    import gymnasium

    import ddpg_her
    from ddpg_her.spaces import goal_input

    trainer = Trainer(toy_goal_env.ENV_ID, TASK, ensemble_config(), [0], [str(tmp_path / "r")],
                      progress=False, tensorboard=False)
    try:
        trainer.run()
        env = gymnasium.make(toy_goal_env.ENV_ID, **TASK)
        obs = [env.reset(seed=s)[0] for s in range(12)]
        batch = {key: np.stack([o[key] for o in obs]) for key in obs[0]}
        x = torch.as_tensor(goal_input(batch["observation"], batch["achieved_goal"],
                                       batch["desired_goal"]))[None]
        want = trainer.collector.scale.to_env(trainer.agent.act(x)[0].double().numpy())
        cells = trainer.agent.cells(x)[0]
    finally:
        trainer.close()
    assert 0 < int(cells.sum()) < 12  # goals of both cells
    policy = ddpg_her.load(tmp_path / "r")
    assert np.allclose(policy(batch), want, atol=1e-6)
    assert np.allclose(policy(obs[0]), want[0], atol=1e-6)


def test_the_ensemble_timing_benchmark_prints_its_figures():
    from cli_tools import run_module

    proc = run_module("benchmarks.ensemble_episode", "--env-id", "toy_goal_env:ToyReach-v0",
                      "--region", "box", "--joints", "2", "--seeds", "2", "--members", "2",
                      "--warmup", "1", "--rounds", "2", "--hidden-sizes", "16", "16",
                      "--updates-per-episode", "4")
    out = json.loads(proc.stdout)
    assert out["ensemble_over_plain"] > 0 and out["partition_fit_s"] >= 0
    assert out["members"] == 2 and out["rounds"] == 2
