"""Many settings in one process (ddpg_her.multi, ddpg_her.train_many) against each run alone,
on the toy goal env."""

import json
import subprocess
from pathlib import Path

import pytest
import torch
import toy_goal_env  # noqa: F401  (registers ToyReach-v0)
from cli_tools import run_module
from toy_goal_env import ENV_ID

from ddpg_her.config import AgentConfig
from ddpg_her.multi import MultiTrainer, Setting, group_settings
from ddpg_her.runfolder import RunFolder
from ddpg_her.trainer import Trainer
from ddpg_her.vecenv import GoalVecEnv

TINY = AgentConfig(episodes=6, eval_every=3, eval_episodes=3, hidden_sizes=(16, 16),
                   updates_per_episode=3, buffer_size=60, batch_size=8, exploration_rate=0.3,
                   warmup_episodes=2)
BOX2 = {"region": "box", "n_joints": 2}
COSTLY = {**BOX2, "action_cost": 0.5}
"""Another reading of the reward: the same layout, ten times the action penalty."""
BOX3 = {"region": "box", "n_joints": 3}
SPEC_PER_PROCESS = ("command", "created", "git", "versions")
"""spec.json keys that say which process wrote a run, not what it is."""


def alone(folder: Path, env_kwargs, seed: int, config=TINY, dtype=torch.float64) -> None:
    trainer = Trainer(ENV_ID, env_kwargs, config, [seed], [str(folder)], dtype=dtype,
                      progress=False, tensorboard=False)
    try:
        trainer.run()
    finally:
        trainer.close()


WEIGHT_RTOL = {torch.float64: 1e-12, torch.float32: 1e-5}
"""How far a weight of a run in a stack may be from the run alone, relative: torch's fused Adam
steps the elements of a stacked tensor in SIMD vectors and a scalar tail, and which of the two
steps agent k's elements depends on where its slice sits, so one step may round differently
(measured: 2e-19 on output biases of 1e-3 after 12 updates in float64; 0 in float32)."""


def same_run(a: Path, b: Path, episode: int) -> None:
    """spec.json (but for the process), eval.csv (but for wall_s), the random states and
    buffer counts equal bitwise; every network, Adam moment and normaliser sum equal to
    `WEIGHT_RTOL`."""
    spec_a, spec_b = (json.loads((d / "spec.json").read_text()) for d in (a, b))
    for key in SPEC_PER_PROCESS:
        spec_a.pop(key), spec_b.pop(key)
    assert spec_a == spec_b
    rows_a, rows_b = (RunFolder(d).read_eval() for d in (a, b))
    assert [{**r, "wall_s": 0} for r in rows_a] == [{**r, "wall_s": 0} for r in rows_b]
    ca, cb = (RunFolder(d).load_checkpoint(episode) for d in (a, b))
    assert ca["rng"]["explore"] == cb["rng"]["explore"]
    assert torch.equal(ca["rng"]["sample"], cb["rng"]["sample"])
    assert ca["buffer_total"] == cb["buffer_total"] and ca["env_steps"] == cb["env_steps"]
    pairs = [((net, key), ca["agent"][net][key], cb["agent"][net][key])
             for net in ("actor", "critic", "actor_target", "critic_target", "normalizer")
             for key in ca["agent"][net]]
    pairs += [((opt, i, key), value, cb["agent"][opt][i][key])
              for opt in ("actor_opt", "critic_opt") for i, state in ca["agent"][opt].items()
              for key, value in state.items()]
    for where, x, y in pairs:
        assert x.dtype == y.dtype and x.shape == y.shape, where
        rtol = WEIGHT_RTOL.get(x.dtype, 0.0)
        assert torch.allclose(x, y, rtol=rtol, atol=rtol * 1e-3), where


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_every_run_of_a_multi_setting_process_is_the_run_alone(tmp_path, dtype):
    """Two readings of one layout in one stack (K = 3) and another joint count as a second
    stack: each seed's run folder is bitwise the one it gets trained alone (small networks)."""
    many = tmp_path / "many"
    settings = [Setting(ENV_ID, BOX2, TINY, (0, 1), (str(many / "a0"), str(many / "a1"))),
                Setting(ENV_ID, BOX3, TINY, (1,), (str(many / "b1"),)),
                Setting(ENV_ID, COSTLY, TINY, (1,), (str(many / "c1"),))]
    trainer = MultiTrainer(settings, dtype=dtype, progress=False, tensorboard=False)
    try:
        assert [t.k for t in trainer.trainers] == [3, 1]
        trainer.run()
    finally:
        trainer.close()
    for name, kwargs, seed in (("a1", BOX2, 1), ("b1", BOX3, 1), ("c1", COSTLY, 1)):
        alone(tmp_path / "alone" / name, kwargs, seed, dtype=dtype)
        same_run(many / name, tmp_path / "alone" / name, TINY.episodes)
    # the reading matters: seed 1 under the costly reward is another run than under the plain
    assert RunFolder(many / "a1").read_eval() != RunFolder(many / "c1").read_eval()


def test_settings_group_by_layout_agent_configuration_and_resume_point(tmp_path):
    gauss = AgentConfig(**{**TINY.to_dict(), "exploration_rate": 0.2, "warmup_episodes": 0})

    def s(kwargs, config=TINY, name="x"):
        return Setting(ENV_ID, kwargs, config, (0,), (str(tmp_path / name),))

    groups = group_settings([s(BOX2, name="a"), s(BOX3, name="b"), s(COSTLY, name="c"),
                             s(BOX2, gauss, name="d")], resume=False)
    assert [[x.run_dirs[0][-1] for x in g] for g in groups] == [["a", "c"], ["b"], ["d"]]
    # the training program takes every setting as one stack, and train_many's dry run says so
    every = [s(BOX2, name="a"), s(BOX3, name="b"), s(BOX2, gauss, name="d")]
    assert group_settings(every, resume=False, env_backend="program") == [every]
    # a setting resumed from another checkpoint is another stack
    alone(tmp_path / "e", BOX2, 0, config=AgentConfig(**{**TINY.to_dict(), "episodes": 3}))
    groups = group_settings([s(BOX2, name="a"), s(BOX2, name="e")], resume=True)
    assert len(groups) == 2


def test_a_layout_mismatch_within_one_stack_is_an_error_naming_the_groups():
    with pytest.raises(ValueError, match=r"group 1 .*n_joints.*3.*one batch needs one layout"):
        GoalVecEnv(ENV_ID, [BOX2, BOX3])


def _train_many(*args: str, cwd: Path, check: bool = True) -> subprocess.CompletedProcess:
    return run_module("ddpg_her.train_many", *args, cwd=cwd, check=check)


TOY = ["--env-id", "toy_goal_env:ToyReach-v0", "--eval-every", "2", "--eval-episodes", "3",
       "--hidden-sizes", "8", "8", "--updates-per-episode", "2", "--warmup-episodes", "1",
       "--batch-size", "8"]


def test_train_many_trains_resumes_and_dry_runs_like_separate_commands(tmp_path):
    units = ["--unit=--region box --joints 2 --seeds 0 1 --out many/a{seed}",
             "--unit=--region box --joints 3 --seeds 0 --out many/b{seed}"]
    _train_many("--no-progress", *units, "--", *TOY, "--episodes", "2", cwd=tmp_path)
    proc = _train_many("--resume", "--dry-run", *units, "--", *TOY, "--episodes", "4",
                       cwd=tmp_path)
    assert [line.split()[:2] for line in proc.stdout.splitlines()] == \
        [["resume", "stack=1"], ["resume", "stack=1"], ["resume", "stack=2"]]
    assert "2 stack(s) of 2, 1 agents" in proc.stderr
    _train_many("--resume", "--no-progress", *units, "--", *TOY, "--episodes", "4",
                cwd=tmp_path)
    # the same runs by ddpg_her.train, one process per unit, uninterrupted
    for unit in units:
        args = unit.partition("=")[2].replace("many/", "single/").split()
        run_module("ddpg_her.train", *args, *TOY, "--episodes", "4", "--no-progress",
                   cwd=tmp_path)
    for name in ("a0", "a1", "b0"):
        same_run(tmp_path / "many" / name, tmp_path / "single" / name, 4)
    done = _train_many("--resume", *units, "--", *TOY, "--episodes", "4", cwd=tmp_path)
    assert done.stderr.count("finished, skipped") == 2


def test_train_many_refuses_process_flags_in_a_unit_and_bad_plans(tmp_path):
    # a budget of 2 episodes, so that a check that lets the flag through fails fast
    proc = _train_many("--unit=--region box --resume", "--", *TOY, "--episodes", "2",
                       cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "process flag(s) --resume" in proc.stderr
    bad = tmp_path / "plan.json"
    bad.write_text('{"units": ["--region box"]}')
    proc = _train_many("--plan", str(bad), cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "each unit a list" in proc.stderr


def test_every_process_flag_a_unit_refuses_is_a_flag_of_train_many():
    """A unit's process flag is refused with "give them to train_many": it must take them."""
    from ddpg_her import train, train_many

    dests = {a.dest for a in train_many.make_parser()._actions}
    assert set(train.PROCESS_FLAGS) <= dests
    args = train_many.make_parser().parse_args(["--env-backend", "batched", "--device", "cuda"])
    assert (args.env_backend, args.device) == ("batched", "cuda")


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_multi_setting_stack_on_cuda_matches_the_runs_alone_to_rounding(tmp_path):
    """On the GPU the batched products may round differently with K; float64 keeps it tight."""
    config = AgentConfig(**{**TINY.to_dict(), "eval_every": 6})
    many = tmp_path / "many"
    settings = [Setting(ENV_ID, BOX2, config, (0,), (str(many / "a0"),)),
                Setting(ENV_ID, COSTLY, config, (1,), (str(many / "c1"),))]
    trainer = MultiTrainer(settings, device="cuda", dtype=torch.float64, progress=False,
                           tensorboard=False)
    try:
        trainer.run()
    finally:
        trainer.close()
    one = Trainer(ENV_ID, COSTLY, config, [1], [str(tmp_path / "c1")], device="cuda",
                  dtype=torch.float64, progress=False, tensorboard=False)
    try:
        one.run()
    finally:
        one.close()
    a, b = (RunFolder(d).load_checkpoint(6)["agent"] for d in (many / "c1", tmp_path / "c1"))
    for net in ("actor", "critic"):
        for key in a[net]:
            assert torch.allclose(a[net][key], b[net][key], rtol=0, atol=1e-10), (net, key)


def test_a_unit_that_cannot_be_split_is_refused_naming_it(tmp_path, capsys):
    """Issue 37 (found by benchmarks/reliability_probe.py): ``--unit "--region 'farbox"`` (an
    unclosed quote) ended in shlex's "No closing quotation" traceback."""
    from ddpg_her import train_many

    with pytest.raises(SystemExit) as stop:
        train_many.main(["--unit", "--region 'farbox --out u", "--dry-run"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "--unit" in err and "\"--region 'farbox --out u\" cannot be split" in err
    assert list(tmp_path.iterdir()) == []
