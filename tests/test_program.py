"""The training program (ddpg_her.program) on the CPU: each piece against today's code path or
an independent reference, the bodies free of host reads, resume and stack independence.

Most tests step the arm with `FirstOrderArm`, a pure-torch stand-in (the program does not
care what moves the arm, and a stand-in keeps the tests fast and lets torch.compile trace a
whole body); the physics kernel behind `envs.stackreach` has tests of its own.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats
import torch

import regions
import ur5kin
from ddpg_her.agent import DDPG
from ddpg_her.buffer import TensorEpisodes, her_goal_steps, her_tensors, pack_tensors
from ddpg_her.config import AgentConfig, HERStrategy
from ddpg_her.program import PADDED, Program, input_index, pad_state, unpad_state
from ddpg_her.runfolder import RunFolder
from ddpg_her.spaces import ActionScale
from envs.physics.model import ur5_plane
from envs.stackreach import StackReach, TorchPlane, plane_heights, proposals_for
from envs.task import action_bounds, compute_reward, compute_success

TINY = dict(hidden_sizes=(16, 16), warmup_episodes=2, eval_every=3, eval_episodes=4,
            updates_per_episode=4, batch_size=8, buffer_size=1000)
TASKS = [dict(region="farbox", n_joints=3), dict(region="unconstrained", n_joints=2),
         dict(region="zheight", n_joints=6)]


class FirstOrderArm:
    """A stand-in arm: each controlled joint moves a fifth of the way to its command per step,
    tool0 by the closed-form FK; tensors only."""

    def __init__(self, tasks, device="cpu"):
        f64 = {"dtype": torch.float64, "device": device}
        self.start = torch.tensor([t.start_q for t in tasks], **f64)
        n = torch.tensor([t.n_joints for t in tasks], device=device)
        self.mask = torch.arange(6, device=device) < n[:, None]
        self.h, self.geometry = tasks[0].base_height, ur5kin.model.geometry()
        self.q, self.v, self.acceleration = (torch.zeros(len(tasks), 6, **f64) for _ in range(3))
        self.q.copy_(self.start)
        self.tool = torch.zeros(len(tasks), 3, **f64)
        self._tool()

    def _tool(self):
        p = ur5kin.closed_form.position(self.q, self.geometry)
        self.tool.copy_(torch.cat([p[:, :2], p[:, 2:] + self.h], -1))

    def step(self, command):
        q = torch.where(self.mask, self.q + 0.2 * (command - self.q), self.q)
        v = (q - self.q) / 0.02
        self.acceleration.copy_((v - self.v) / 0.02)
        self.v.copy_(v)
        self.q.copy_(q)
        self._tool()

    def reset_where(self, mask):
        m = mask[:, None]
        self.q.copy_(torch.where(m, self.start, self.q))
        self.v.masked_fill_(m, 0.0)
        self.acceleration.masked_fill_(m, 0.0)
        self._tool()


def make_program(tmp_path, tasks=TASKS, seeds=(0, 1, 2), name="run", dtype=torch.float64,
                 **config):
    """The program of ``tasks`` on the stand-in arm; ``config``: AgentConfig fields, and
    the constructor's ``window``, ``budget`` and ``resume``."""
    own = {key: config.pop(key) for key in ("window", "budget", "resume") if key in config}
    cfg = AgentConfig(**{**TINY, "episodes": 6, **config})
    return Program("UR5Reach-v0", tasks, cfg, list(seeds),
                   [tmp_path / f"{name}{i}" for i in range(len(seeds))], progress=False,
                   dtype=dtype, dynamics=FirstOrderArm, **own)


# ---------------------------------------------------------------------------- the update
def test_the_padded_stack_updates_each_agent_as_ddpg_alone_to_1e10_in_float64():
    """Agents of 2 and 3 joints embedded in one stack of 6: after several updates on the same
    minibatches, each agent's weights equal those of a DDPG of its own dims, and what the
    padding holds stays exactly zero."""
    cfg = AgentConfig(hidden_sizes=(32, 24), normalize_obs=True)
    joints, batch = (2, 3), 16
    gen = torch.Generator().manual_seed(7)
    alone = [DDPG(cfg, 3 * n + 6, n, dtype=torch.float64,
                  init_generators=[torch.Generator().manual_seed(11 + n)]) for n in joints]
    for a in alone:  # normaliser statistics that are not the identity
        x = torch.randn(50, a.in_dim, generator=gen, dtype=torch.float64) * 2.0 + 0.5
        a.normalizer.update(0, x.numpy())
    stack = DDPG(cfg, PADDED.in_dim, PADDED.act_dim, dtype=torch.float64,
                 init_generators=[torch.Generator() for _ in joints])
    stack.load_agent_states([pad_state(a.agent_state(0), stack.agent_state(i), n, 32)
                             for i, (a, n) in enumerate(zip(alone, joints, strict=True))])
    for _ in range(5):
        padded = []
        for a, n in zip(alone, joints, strict=True):
            x, x2 = (torch.randn(1, batch, a.in_dim, generator=gen, dtype=torch.float64)
                     for _ in range(2))
            u = torch.rand(1, batch, n, generator=gen, dtype=torch.float64) * 2 - 1
            r = torch.randn(1, batch, 1, generator=gen, dtype=torch.float64)
            term = (torch.rand(1, batch, 1, generator=gen) < 0.2).double()
            a.update(x, u, r, x2, term)
            px, px2 = (torch.zeros(1, batch, PADDED.in_dim, dtype=torch.float64)
                       for _ in range(2))
            px[..., input_index(n)], px2[..., input_index(n)] = x, x2
            pu = torch.zeros(1, batch, 6, dtype=torch.float64)
            pu[..., :n] = u
            padded.append((px, pu, r, px2, term))
        stack.update(*(torch.cat(parts) for parts in zip(*padded, strict=True)))
    for i, (a, n) in enumerate(zip(alone, joints, strict=True)):
        got = unpad_state(stack.agent_state(i), n, 32)
        want = a.agent_state(0)
        for net in ("actor", "critic", "actor_target", "critic_target"):
            for p, v in want[net].items():
                torch.testing.assert_close(got[net][p], v, rtol=0, atol=1e-10, msg=f"{net}.{p}")
        for opt in ("actor_opt", "critic_opt"):
            for j, entry in want[opt].items():
                for key, v in entry.items():
                    torch.testing.assert_close(got[opt][j][key], v, rtol=0, atol=1e-10)
        full = stack.agent_state(i)
        assert torch.all(full["actor"]["l3.weight"][:, n:] == 0)
        assert torch.all(full["actor"]["l3.bias"][:, n:] == 0)
        dead = [j for j in range(PADDED.in_dim) if j not in input_index(n)]
        assert torch.all(full["critic"]["l1.weight"][dead] == 0)
        assert torch.all(full["critic"]["l2.weight"][32 + n:] == 0)


# ---------------------------------------------------------------------------- goals
@pytest.mark.parametrize("task", [dict(region="farbox", n_joints=3),
                                  dict(region="zheight", n_joints=2)])
def test_device_goals_follow_the_joint_space_samplers_law(task):
    """Goals drawn on the device against regions.JointSpaceSampler's: a two-sample KS test
    per coordinate, and the device's acceptance inside the binomial 99.9 % interval of the
    sampler's own proposals."""
    env = StackReach(400, [task], dynamics=FirstOrderArm)
    rng = np.random.default_rng(3)
    goals = env.draw_goals(lambda first, count: torch.from_numpy(
        rng.random((400, count, 6))))
    assert int(env.goal_misses) == 0
    sampler = regions.JointSpaceSampler(regions.get(task["region"]), task["n_joints"],
                                        env.tasks[0].start_q)
    ref = sampler.sample(400, np.random.default_rng(4)).goals
    for axis in range(3):
        assert scipy.stats.ks_2samp(goals[:, axis].numpy(), ref[:, axis]).pvalue > 1e-3
    proposals = 40_000
    _, ok = StackReach(1, [task], dynamics=FirstOrderArm).accepts(
        torch.from_numpy(rng.random((1, proposals, 6))))
    rate = ok.double().mean().item()
    batch = sampler.sample(2000, np.random.default_rng(5))
    ref_rate = len(batch.goals) / batch.proposals
    # both are binomial estimates of one acceptance: their difference within 3.3 sigma
    sigma = math.sqrt(ref_rate * (1 - ref_rate) * (1 / proposals + 1 / batch.proposals))
    assert abs(rate - ref_rate) < 3.3 * sigma, (rate, ref_rate)


def test_the_device_plane_check_is_ur5kins():
    """The goals' plane test on the device against ur5kin.link_heights (the numpy check every
    host path uses), moving links only."""
    q = np.random.default_rng(3).uniform(-np.pi, np.pi, (300, 6))
    plane = TorchPlane.from_plane(ur5_plane(), "cpu", torch.float64)
    heights = plane_heights(torch.from_numpy(q), plane, 0.5)
    np.testing.assert_allclose(heights.numpy(), ur5kin.link_heights(q, 0.5)[:, 1:], atol=1e-12)


def test_proposals_bound_the_miss_probability():
    p = proposals_for(0.05, 1e-9)
    assert (1 - 0.05) ** p <= 1e-9 < (1 - 0.05) ** (p - 1)
    with pytest.raises(ValueError, match="acceptance"):
        proposals_for(0.0)


def test_a_stack_refuses_tasks_that_differ_elsewhere():
    with pytest.raises(ValueError, match="success_radius"):
        StackReach(2, [dict(region="farbox"), dict(region="farbox", success_radius=0.05)],
                   dynamics=FirstOrderArm)
    with pytest.raises(ValueError, match="contact_model"):
        StackReach(1, [dict(region="farbox", contact_model="compliant")], dynamics=FirstOrderArm)
    with pytest.raises(ValueError, match="multiple"):
        StackReach(3, TASKS[:2], dynamics=FirstOrderArm)


# ---------------------------------------------------------------------------- the store
def test_the_store_writes_the_rows_todays_collector_writes(tmp_path):
    """After a training episode, the rows the program stored for each agent (at its own
    dims) equal what ddpg_her.collect packs for the same episode: pack_tensors of the real
    transitions, then the HER 'final' copy from her_tensors with the rewards of
    envs.task.compute_reward (numpy, the env's own function)."""
    prog = make_program(tmp_path)
    for _ in range(3):
        before = prog.total.clone()
        prog.step()
    prog.buffer.total[:] = prog.total.numpy()
    for k, n in enumerate(prog.joints):
        task = prog.env.tasks[k]
        length = int(prog.length[k])
        eps = TensorEpisodes(
            observation=prog.obs[k:k + 1, :, [b * 6 + j for b in range(3) for j in range(n)]],
            achieved_goal=prog.achieved[k:k + 1], desired_goal=prog.env.goal[k:k + 1],
            action=prog.action[k:k + 1, :, :n], reward=prog.reward[k:k + 1],
            terminated=prog.terminated[k:k + 1], length=prog.length[k:k + 1],
            success=prog.success[k:k + 1])
        scale = ActionScale(*action_bounds(task))
        rows = pack_tensors(eps.observation[0], eps.achieved_goal[0], eps.desired_goal[0],
                            eps.action[0], eps.reward[0], eps.terminated[0], scale)[:length]

        def reward_fn(ag, g, a, task=task):
            return torch.as_tensor(compute_reward(ag.numpy(), g.numpy(), {"action": a.numpy()},
                                                  task))

        def terminated_fn(ag, g, a, task=task):
            return torch.as_tensor(compute_success(ag.numpy(), g.numpy(), task)
                                   & task.terminate_on_success)

        steps = her_goal_steps(HERStrategy.FINAL, length, 4, np.random.default_rng(0))
        goal, reward, term, her_len = her_tensors(eps, np.zeros(1, dtype=int), steps,
                                                  reward_fn, terminated_fn)
        her = pack_tensors(eps.observation, eps.achieved_goal, goal, eps.action, reward, term,
                           scale)[0, :int(her_len[0])]
        start, stored = prog.chunks.since(k, int(before[k]))
        assert start == int(before[k])
        np.testing.assert_array_equal(stored, torch.cat([rows, her]).numpy())


# ---------------------------------------------------------------------------- no host reads
HOST_READS = ("item", "cpu", "numpy", "tolist", "__bool__", "__int__", "__float__")
UPLOADS = ("tensor", "as_tensor", "from_numpy")


@pytest.fixture
def host_counter(monkeypatch):
    """Counts the calls that read a tensor on the host or make one from host data."""
    calls: list[str] = []

    def counting(owner, name):
        original = getattr(owner, name)

        def wrapper(*args, **kwargs):
            calls.append(name)
            return original(*args, **kwargs)
        monkeypatch.setattr(owner, name, wrapper)

    for name in HOST_READS:
        counting(torch.Tensor, name)
    for name in UPLOADS:
        counting(torch, name)
    return calls


def test_an_episode_reads_nothing_on_the_host(tmp_path, host_counter):
    """Training episodes (warm-up and acting, with their updates) make no host read and no
    upload; the test session's interval reads back what eval.csv needs, once."""
    prog = make_program(tmp_path, episodes=9)
    prog.step()  # the first runs make lazily created state (Adam's moments)
    prog.step()
    prog.step()  # a test session and a checkpoint
    host_counter.clear()
    prog.step()  # acting, with updates
    prog.step()
    assert host_counter == []
    prog.step()  # the session: its reads are the eval rows', the checkpoint's
    assert host_counter


@pytest.mark.parametrize("body", ["warm", "act", "learn", "test"])
def test_each_body_compiles_whole(tmp_path, body):
    """torch.compile(fullgraph=True) traces each body without a graph break: no host value,
    no data-dependent Python branch (dynamo's own tracing; the eager backend keeps it fast)."""
    short = [dict(task, max_episode_steps=3) for task in TASKS]  # a short unrolled loop
    prog = make_program(tmp_path, tasks=short, warmup_episodes=1, updates_per_episode=2)
    prog.step()
    prog.step()  # Adam's state exists
    run = prog._bodies[body].body
    torch._dynamo.reset()
    torch.compile(run, fullgraph=True, backend="eager")()


# ---------------------------------------------------------------------------- runs
def _eval_rows(folder):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in RunFolder(folder).read_eval()]


def test_resume_continues_exactly(tmp_path):
    whole = make_program(tmp_path, name="whole")
    whole.run()
    whole.close()
    part = make_program(tmp_path, name="part", episodes=3)
    part.run()
    part.close()
    rest = Program("UR5Reach-v0", TASKS, AgentConfig(**{**TINY, "episodes": 6}), [0, 1, 2],
                   [tmp_path / f"part{i}" for i in range(3)], resume=True, progress=False,
                   dtype=torch.float64, dynamics=FirstOrderArm)
    assert rest.episode == 3
    rest.run()
    rest.close()
    for i in range(3):
        assert _eval_rows(tmp_path / f"part{i}") == _eval_rows(tmp_path / f"whole{i}")


def test_an_agent_trains_alike_alone_and_in_a_stack(tmp_path):
    """Seed 1 with 2 joints alone and beside agents of 3 and 6 joints: the same eval.csv."""
    alone = make_program(tmp_path, tasks=TASKS[1:2], seeds=(1,), name="alone")
    alone.run()
    stacked = make_program(tmp_path, name="stack")
    stacked.run()
    assert _eval_rows(tmp_path / "alone0") == _eval_rows(tmp_path / "stack1")


def test_ddpg_her_load_reads_a_program_run(tmp_path):
    """A program run folder is a run folder: ddpg_her.load's policy acts as the stack's
    agent does on the same observation."""
    import ddpg_her

    prog = make_program(tmp_path)
    prog.run()
    policy = ddpg_her.load(tmp_path / "run1")  # the 2-joint agent
    assert policy.spec["dims"]["act_dim"] == 2
    rng = np.random.default_rng(1)
    obs = {"observation": rng.normal(size=6), "achieved_goal": rng.normal(size=3),
           "desired_goal": rng.normal(size=3)}
    padded = np.zeros(24)
    padded[input_index(2)] = np.concatenate([obs["observation"],
                                            obs["desired_goal"] - obs["achieved_goal"],
                                            obs["desired_goal"]])
    x = torch.zeros(3, 1, 24, dtype=torch.float64)
    x[1, 0] = torch.from_numpy(padded)
    u = prog.agent.act(x)[1, 0, :2]
    np.testing.assert_allclose(policy(obs), (u * math.pi).numpy(), rtol=1e-6, atol=1e-6)


def test_a_window_run_saves_eval_rows_and_policies_only_and_refuses_resume(tmp_path):
    """A window run trains as a normal run does (the same eval.csv: the saves read the device
    and touch nothing it trains with), writes no buffer chunk and one checkpoint, at its end,
    whose policy ddpg_her.load reads as the normal run's; --resume of it is refused."""
    import ddpg_her

    normal = make_program(tmp_path, name="normal")
    normal.run()
    normal.close()
    window = make_program(tmp_path, name="window", window=True)
    rows_after_first_session = None
    while not window.done:
        window.step()
        if window.episode == 3:
            rows_after_first_session = _eval_rows(tmp_path / "window0")
            assert not (tmp_path / "window0" / "checkpoints").exists()
    window.close()
    assert len(rows_after_first_session) == 1  # eval.csv at every session
    for i in range(3):
        run = tmp_path / f"window{i}"
        assert _eval_rows(run) == _eval_rows(tmp_path / f"normal{i}")
        assert not (run / "buffer").exists()
        assert list(RunFolder(run).checkpoints()) == [6]
        assert RunFolder(run).read_spec()["program"]["window"] is True
        obs = {"observation": np.linspace(-1, 1, 3 * [3, 2, 6][i]),
               "achieved_goal": np.array([0.3, 0.1, 0.5]),
               "desired_goal": np.array([0.4, -0.2, 0.6])}
        np.testing.assert_array_equal(ddpg_her.load(run)(obs),
                                      ddpg_her.load(tmp_path / f"normal{i}")(obs))
    with pytest.raises(ValueError, match=r"holds a window run .* cannot be resumed"):
        make_program(tmp_path, name="window", window=True, resume=True)
    with pytest.raises(ValueError, match="a window run starts afresh"):
        make_program(tmp_path, name="normal", window=True, resume=True, episodes=9)


def test_choose_episodes_takes_the_largest_budget_projected_to_fit():
    """The window plan's arithmetic (benchmarks/GPU.md): 720 s of training take 20,000
    episodes at 36 ms each (after 30 s spent at episode 200: 30 + 19,800 x 0.036 = 742.8 s,
    over; 34 ms fits: 703.2 s), 10,000 at 70 ms (716 s), 2,500 at 300 ms (720 s), and when
    nothing fits, the smallest left."""
    from ddpg_her.loop import choose_episodes

    choices = (20000, 10000, 5000, 2500)
    assert choose_episodes(30.0, 200, 0.036, 720, choices)[0] == 10000
    chosen, end = choose_episodes(30.0, 200, 0.034, 720, choices)
    assert chosen == 20000 and end == pytest.approx(703.2)
    assert choose_episodes(30.0, 200, 0.070, 720, choices)[0] == 10000
    assert choose_episodes(30.0, 200, 0.300, 720, choices) == (2500, pytest.approx(720.0))
    assert choose_episodes(30.0, 200, 10.0, 720, choices)[0] == 2500
    assert choose_episodes(600.0, 6000, 0.5, 720, choices)[0] == 10000  # 5000 is past


@pytest.mark.parametrize(("seconds", "chosen"), [(12.0, 6), (14.0, 12)])
def test_a_window_run_trains_the_budget_its_measured_rate_fits(tmp_path, seconds, chosen):
    """With a fake clock at 10 s after the start at the first test session and one more
    second at each further one (1/3 s per episode, eval_every 3): at the second session
    (episode 6, 11 s) 12 episodes project to 11 + 6/3 = 13 s. A 12 s budget stops at 6, a
    14 s one trains 12; spec.json records the choice."""
    from ddpg_her.loop import Budget

    ticks = iter(10.0 + np.arange(10))
    budget = Budget(seconds, (12, 6), start=0.0, clock=lambda: float(next(ticks)))
    prog = make_program(tmp_path, episodes=12, window=True, budget=budget)
    prog.run()
    prog.close()
    rows = RunFolder(tmp_path / "run0").read_eval()
    assert [int(r["episode"]) for r in rows] == list(range(3, chosen + 1, 3))
    spec = RunFolder(tmp_path / "run0").read_spec()
    assert spec["agent"]["episodes"] == chosen
    assert spec["program"]["budget"]["ms_per_episode"] == pytest.approx(1e3 / 3, abs=1e-3)
    assert list(RunFolder(tmp_path / "run0").checkpoints()) == [chosen]
    with pytest.raises(ValueError, match="a time budget is a window run's"):
        make_program(tmp_path, name="other", episodes=12, budget=budget)


def test_prune_after_a_save_reads_no_chunk(tmp_path, monkeypatch):
    """Pruning learns each chunk's span from its name: with np.load refused it deletes the
    chunks wholly before keep_from and keeps the rest; a chunk named as before (no span in
    its name) is still read to learn it."""
    folder = RunFolder(tmp_path / "run")
    for episode, start in ((1, 0), (2, 5), (3, 9)):
        folder.save_chunk(episode, start, np.zeros((start // 2 + 4, 3)))
    old = tmp_path / "run" / "buffer" / "episode-000004.npz"
    np.savez(old, start=np.int64(13), rows=np.zeros((2, 3)))

    def refuse(*args, **kwargs):
        raise AssertionError("np.load called")

    with monkeypatch.context() as m:
        m.setattr(np, "load", refuse)
        folder.prune(upto=3, keep_from=9)  # deletes the old-named chunk of episode 4 unread
        assert sorted(p.name for p in (tmp_path / "run" / "buffer").iterdir()) == [
            "episode-000002.5-11.npz", "episode-000003.9-17.npz"]
        folder.prune(upto=3, keep_from=11)
        assert [p.name for p in (tmp_path / "run" / "buffer").iterdir()] == [
            "episode-000003.9-17.npz"]
    np.savez(old, start=np.int64(13), rows=np.zeros((2, 3)))
    folder.prune(upto=4, keep_from=15)  # the old name: read, ends at 15, deleted
    assert [p.name for p in (tmp_path / "run" / "buffer").iterdir()] == [
        "episode-000003.9-17.npz"]
    assert [(s, len(r)) for s, r in folder.chunks(upto=9)] == [(9, 8)]


# ---------------------------------------------------------------------------- on a GPU
@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (the GPU window's "
                    "stage 1 runs it: benchmarks/gpu_grid.sh)")
@pytest.mark.parametrize(("arm", "deterministic"),
                         [("stand-in", False), ("kernel", False), ("kernel", True)])
def test_the_captured_bodies_equal_the_same_bodies_run_eagerly_on_cuda(tmp_path, arm,
                                                                        deterministic):
    """The four bodies replayed from CUDA graphs give what the same code gives eagerly on
    the same device: the same eval rows and weights (the same kernels, so the same bits).
    ``deterministic``: under torch.use_deterministic_algorithms(True), as
    ddpg_her.train.start_process runs every training (the store's index_put_ then takes
    its sort path on CUDA, which must capture too)."""
    import os

    if arm == "kernel" and os.environ.get("TRITON_INTERPRET") == "1":
        pytest.skip("TRITON_INTERPRET=1 in this process (tests/test_stack_dynamics.py sets it "
                    "when collected): run the gpu tests with TRITON_INTERPRET=0")
    dynamics = FirstOrderArm if arm == "stand-in" else None
    runs = {}
    was = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(deterministic, warn_only=True)
    try:
        for capture in (False, True):
            prog = Program("UR5Reach-v0", TASKS, AgentConfig(**{**TINY, "episodes": 9}),
                           [0, 1, 2], [tmp_path / f"{capture}{i}" for i in range(3)],
                           progress=False, device="cuda", capture=capture, dynamics=dynamics)
            prog.run()
            runs[capture] = (prog, [_eval_rows(tmp_path / f"{capture}{i}") for i in range(3)])
            prog.close()
    finally:
        torch.use_deterministic_algorithms(was)
    assert runs[True][1] == runs[False][1]
    bodies = runs[True][0]._bodies  # warm-up episodes 2: the "warm" body is never captured
    assert all(bodies[name].replays > 0 for name in ("act", "learn", "test"))
    for a, b in zip(runs[True][0].agent.actor.parameters(),
                    runs[False][0].agent.actor.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_train_many_runs_a_mixed_stack_on_the_arm_kernel(tmp_path):
    """The command line end to end, with the real arm (envs.physics.stack on the CPU): units
    of 2 and 6 joints as one program stack; every run folder has its test sessions, and
    spec.json records the program and its streams."""
    import json
    import subprocess
    import sys

    common = ("--episodes 4 --eval-every 2 --eval-episodes 3 --warmup-episodes 1 "
              "--hidden-sizes 16 16 --updates-per-episode 2 --batch-size 8 --buffer-size 1000 "
              "--task max_episode_steps=10")
    out = subprocess.run(
        [sys.executable, "-m", "ddpg_her.train_many", "--env-backend", "program", "--threads",
         "1", "--no-progress",
         f"--unit=--region unconstrained --joints 2 --seeds 0 1 {common} "
         f"--out {tmp_path}/u2/s{{seed}}",
         f"--unit=--region farbox --joints 6 --seed 0 {common} --out {tmp_path}/f6/s{{seed}}"],
        capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    for run in ("u2/s0", "u2/s1", "f6/s0"):
        rows = RunFolder(tmp_path / run).read_eval()
        assert [int(r["episode"]) for r in rows] == [2, 4]
        assert all(0 <= int(r["successes"]) <= 3 for r in rows)
        spec = json.loads((tmp_path / run / "spec.json").read_text())
        assert spec["env_backend"] == "program" and spec["program"]["streams"]
    assert "3 agents of 2 units in 1 stack(s): 3" in out.stderr


def test_a_window_run_from_the_command_line_chooses_its_budget_and_refuses_resume(tmp_path):
    """ddpg_her.train --window --budget-seconds: the budget line on stderr, spec.json's
    record, no buffer folder; the same command with --resume ends with one clear line."""
    import subprocess
    import sys

    command = [sys.executable, "-m", "ddpg_her.train", "--env-backend", "program", "--window",
               "--budget-seconds", "600", "--region", "unconstrained", "--joints", "2",
               "--episodes", "4", "--eval-every", "1", "--eval-episodes", "2",
               "--warmup-episodes", "1", "--hidden-sizes", "8", "8", "--updates-per-episode",
               "2", "--batch-size", "8", "--buffer-size", "1000", "--task",
               "max_episode_steps=5", "--threads", "1", "--no-progress",
               "--out", str(tmp_path / "run")]
    first = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr[-2000:]
    assert "window budget:" in first.stderr and "-> 4 episodes" in first.stderr
    spec = RunFolder(tmp_path / "run").read_spec()
    assert spec["program"]["window"] and spec["program"]["budget"]["choices"] == [4, 2, 1]
    assert not (tmp_path / "run" / "buffer").exists()
    again = subprocess.run([*command, "--resume", "--episodes", "8"], capture_output=True,
                           text=True, timeout=600)
    assert again.returncode == 2
    assert "holds a window run" in again.stderr and "cannot be resumed" in again.stderr


def test_the_save_prune_benchmark_times_both_namings():
    """benchmarks.save_prune, tiny: both folders keep every chunk of a full buffer, and a
    prune that opens the chunks is timed beside one that reads their names."""
    import json
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-m", "benchmarks.save_prune", "--buffer-size", "40",
                          "--chunk-rows", "10", "--width", "3", "--rounds", "1"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    result = json.loads(run.stdout)
    assert result["chunks_per_agent"] == 4
    assert result["chunks_kept"] == {"spans_named": 4, "opened": 4}
    assert all(v > 0 for v in result["ms_per_agent"].values())
