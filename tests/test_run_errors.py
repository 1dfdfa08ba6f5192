"""Issue 16 on run folders, the trainer and the command line: every bad input, corrupt file and
misuse gets a clear error naming it, or a safe recovery that says so (issue 15, item 3: one
torch-free run-folder module)."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from toy_goal_env import ENV_ID

from ddpg_her.config import AgentConfig
from ddpg_her.runfolder import RunFolder
from ddpg_her.trainer import Trainer

pytestmark = pytest.mark.xdist_group("test_run_errors")
"""Under pytest-xdist one worker runs this module, so that the finished 12-episode run (`finished`)
is trained once."""

TASK = {"region": "box", "n_joints": 2}
TINY = AgentConfig(episodes=12, eval_every=3, eval_episodes=4, hidden_sizes=(16, 16),
                   updates_per_episode=4, buffer_size=70, batch_size=8, exploration_rate=0.3,
                   warmup_episodes=2)
ROOT = Path(__file__).parent.parent


@pytest.fixture(autouse=True)
def one_thread():
    """One torch thread; and the CPU's subnormal flush, which the trainer sets process-wide,
    back to its default afterwards (hypothesis in later test modules refuses to run with it)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
    torch.set_flush_denormal(False)


def train(dirs, seeds=(0,), config=TINY, task=TASK, **kwargs):
    trainer = Trainer(ENV_ID, task, config, list(seeds), [str(d) for d in dirs],
                      progress=False, tensorboard=False, **kwargs)
    try:
        return trainer.run()
    finally:
        trainer.close()


def with_episodes(n: int) -> AgentConfig:
    return AgentConfig(**{**TINY.to_dict(), "episodes": n})


def eval_rows(run_dir) -> list[list[str]]:
    """eval.csv without its wall-clock column."""
    with open(Path(run_dir) / "eval.csv", newline="") as f:
        return [row[:-1] for row in csv.reader(f)]


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished 12-episode run (checkpoints 9 and 12 kept); tests copy it before changing it."""
    path = tmp_path_factory.mktemp("finished") / "run"
    train([path])
    return path


def copy_of(run: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(run, out)
    return out


# --- item 3 of issue 15: one run-folder module, free of torch ----------------------------------
def test_reading_a_run_folder_imports_neither_torch_nor_pinocchio(finished):
    code = ("import sys; from ddpg_her.runfolder import read_run, RunFolder; "
            f"run = read_run({str(finished)!r}); RunFolder({str(finished)!r}).read_eval(); "
            "import analysis.runs, ddpg_her.summary; "
            f"analysis.runs.find_runs([{str(finished.parent)!r}]); "
            f"ddpg_her.summary.summarize([{str(finished)!r}], 20); "
            "print(run.seed, len(run.episode), sorted(m for m in ('torch', 'pinocchio') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, timeout=120, check=True)
    assert out.stdout.split() == ["0", "4", "[]"], out.stdout


def test_a_run_analysis_cannot_read_is_an_error_naming_it(tmp_path, finished):
    from analysis.runs import find_runs

    run = copy_of(finished, tmp_path)
    other = tmp_path / "not-a-run"
    other.mkdir()
    (other / "spec.json").write_text(json.dumps({"format": "something-else"}))
    assert [r.path for r in find_runs([tmp_path])] == [run]  # another tool's spec.json
    text = (run / "spec.json").read_text()
    (run / "spec.json").write_text(text[: len(text) // 2])  # truncated
    with pytest.raises(ValueError, match=str(run / "spec.json")):
        find_runs([tmp_path])


# --- resuming -------------------------------------------------------------------------------
def test_resume_may_not_shrink_the_episode_budget(tmp_path, finished):
    run = copy_of(finished, tmp_path)
    before = (run / "spec.json").read_text()
    with pytest.raises(ValueError, match=r"planned for 12 episodes.*may only grow.*got 6"):
        Trainer(ENV_ID, TASK, with_episodes(6), [0], [str(run)], resume=True)
    assert (run / "spec.json").read_text() == before


def test_checkpoints_without_spec_json_are_a_run_and_carry_their_configuration(tmp_path,
                                                                              finished):
    run = copy_of(finished, tmp_path)
    (run / "spec.json").unlink()
    with pytest.raises(ValueError, match=r"already holds checkpoints of a run \(its spec.json"):
        Trainer(ENV_ID, TASK, TINY, [0], [str(run)])
    gamma = AgentConfig(**{**TINY.to_dict(), "gamma": 0.5})
    with pytest.raises(ValueError, match=r"episode-000012\.pt holds a run of another task or "
                                         r"agent; differing: agent\.gamma \(was 0\.98"):
        Trainer(ENV_ID, TASK, gamma, [0], [str(run)], resume=True)
    with pytest.raises(ValueError, match=r"differing: env_kwargs.*task"):
        Trainer(ENV_ID, {**TASK, "n_joints": 3}, TINY, [0], [str(run)], resume=True)
    assert not (run / "spec.json").exists()  # nothing written by a refused resume
    train([run], config=with_episodes(15), resume=True)  # the right configuration continues
    whole = tmp_path / "whole"
    train([whole], config=with_episodes(15))
    assert eval_rows(run) == eval_rows(whole)


@pytest.mark.parametrize("damage", ["truncated", "empty"])
def test_a_corrupt_latest_checkpoint_falls_back_to_the_older_one_and_says_so(tmp_path, finished,
                                                                            damage):
    run = copy_of(finished, tmp_path)
    latest = run / "checkpoints" / "episode-000012.pt"
    data = latest.read_bytes()
    latest.write_bytes(data[: len(data) // 2] if damage == "truncated" else b"")
    with pytest.warns(UserWarning, match=rf"{latest}.*older checkpoint of episode 9"):
        train([run], resume=True)
    assert eval_rows(run) == eval_rows(finished)  # episodes 10-12 trained again, identically
    assert torch.load(latest, weights_only=True)["episode"] == 12


def test_a_corrupt_only_checkpoint_is_an_error_naming_it(tmp_path, finished):
    run = copy_of(finished, tmp_path)
    for path in (run / "checkpoints").iterdir():
        path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(ValueError, match=r"episode-000009\.pt cannot be read as a checkpoint"):
        Trainer(ENV_ID, TASK, TINY, [0], [str(run)], resume=True)


def test_a_truncated_buffer_chunk_is_named(tmp_path, finished):
    run = copy_of(finished, tmp_path)
    chunks = sorted((run / "buffer").iterdir())
    first, last = chunks[0], chunks[-1]
    last.write_bytes(last.read_bytes()[:50])  # only the latest checkpoint needs it: fall back
    with pytest.warns(UserWarning, match=rf"{last} cannot be read as a buffer chunk"):
        Trainer(ENV_ID, TASK, TINY, [0], [str(run)], resume=True).close()
    run = copy_of(finished, tmp_path / "again")
    first = run / "buffer" / first.name
    first.write_bytes(first.read_bytes()[:50])  # every checkpoint needs it: an error
    with pytest.raises(ValueError, match=rf"{first} cannot be read as a buffer chunk"):
        Trainer(ENV_ID, TASK, TINY, [0], [str(run)], resume=True)


def test_a_truncated_spec_json_is_named(tmp_path, finished):
    run = copy_of(finished, tmp_path)
    text = (run / "spec.json").read_text()
    (run / "spec.json").write_text(text[:40])
    with pytest.raises(ValueError, match=rf"{run / 'spec.json'} cannot be read as JSON"):
        Trainer(ENV_ID, TASK, TINY, [0], [str(run)], resume=True)


def test_orphaned_temporary_files_are_removed_at_the_next_start(tmp_path, finished):
    run = copy_of(finished, tmp_path)
    orphans = [run / ".eval.csv.tmp123", run / "checkpoints" / ".episode-000015.pt.tmp77",
               run / "buffer" / ".episode-000015.npz.tmp77"]
    for path in orphans:
        path.write_bytes(b"x" * 1000)
    keep = run / "notes.tmp1"  # not a name atomic_write makes
    keep.write_text("mine")
    with pytest.raises(ValueError, match="already holds a run"):
        Trainer(ENV_ID, TASK, TINY, [0], [str(run)])
    assert all(path.exists() for path in orphans)  # a refused start touches nothing
    train([run], config=with_episodes(15), resume=True)
    assert not any(path.exists() for path in orphans)
    assert keep.read_text() == "mine"


# --- ddpg_her.summary -------------------------------------------------------------------------
def test_summary_names_a_garbage_spec_json(tmp_path, finished, capsys):
    from ddpg_her.summary import main

    run = copy_of(finished, tmp_path)
    (run / "spec.json").write_bytes(b"\x00\x01garbage")
    with pytest.raises(SystemExit) as exit_:
        main([str(run)])
    assert exit_.value.code == 2
    assert f"{run / 'spec.json'} cannot be read as JSON" in capsys.readouterr().err


# --- the command line -------------------------------------------------------------------------
CLI_TINY = ["--env-id", f"toy_goal_env:{ENV_ID}", "--region", "box", "--episodes", "2",
            "--eval-every", "1", "--eval-episodes", "2", "--hidden-sizes", "8", "8",
            "--updates-per-episode", "2", "--warmup-episodes", "1", "--no-progress",
            "--no-tensorboard"]


def cli_error(capsys, *args: str) -> str:
    """Run ``python -m ddpg_her.train ARGS`` in-process; expect a usage error, return it."""
    from ddpg_her.train import main

    with pytest.raises(SystemExit) as exit_:
        main(list(args))
    assert exit_.value.code == 2
    return capsys.readouterr().err


@pytest.mark.parametrize("flags, message", [
    (["--joints", "2", "--task", "n_joints=3"],
     "--joints and --task n_joints=3 give the task field 'n_joints' two values (2, 3)"),
    (["--task", "region=zheight"],
     "--region and --task region=\"zheight\" give the task field 'region' two values"),
    (["--task", "lag=0.5", "--task", "lag=0.25"], "give the task field 'lag' two values"),
])
def test_a_field_given_twice_with_different_values_is_an_error(tmp_path, capsys, flags,
                                                                message):
    err = cli_error(capsys, *CLI_TINY, *flags, "--out", str(tmp_path / "run"))
    assert message in err, err
    assert not (tmp_path / "run").exists()


def test_a_field_given_twice_with_one_value_and_task_joints_name_the_folder(tmp_path, capsys):
    from ddpg_her.train import main

    out = str(tmp_path / "{region}-j{joints}")
    assert main([*CLI_TINY, "--task", "n_joints=4", "--task", "region=box", "--out", out]) == 0
    spec = json.loads((tmp_path / "box-j4" / "spec.json").read_text())
    assert spec["task"]["n_joints"] == 4 and spec["task"]["region"] == "box"


def test_an_env_id_whose_module_is_missing_is_a_usage_error(tmp_path, capsys):
    err = cli_error(capsys, *CLI_TINY, "--env-id", "nosuchmod:Foo-v0", "--out",
                    str(tmp_path / "run"))
    assert "--env-id nosuchmod:Foo-v0: cannot import" in err and "nosuchmod" in err


@pytest.mark.parametrize("flag, value, expected", [
    ("--episodes", "-5", "episodes=-5 (expected an integer >= 0)"),
    ("--gamma", "2", "gamma=2.0 (expected a number in [0, 1])"),
    ("--batch-size", "0", "batch_size=0 (expected an integer >= 1)"),
    ("--tau", "0", "tau=0.0 (expected a number in (0, 1])"),
])
def test_agent_configuration_errors_name_the_valid_range(tmp_path, capsys, flag, value,
                                                          expected):
    err = cli_error(capsys, *CLI_TINY, flag, value, "--out", str(tmp_path / "run"))
    assert expected in err, err


def test_help_names_each_checked_fields_range(capsys):
    from ddpg_her.config import VALID
    from ddpg_her.train import make_parser

    parser = make_parser()
    helps = {a.dest: a.help for a in parser._actions}
    assert set(VALID) <= set(helps)
    for name, kind in VALID.items():
        assert f"Valid: {kind.words}" in " ".join(helps[name].split()), name


# --- the README's claim on --seeds 0 1 vs --seed 0 --------------------------------------------
@pytest.mark.parametrize("dtype, bound", [(torch.float64, 1e-13), (torch.float32, 1e-5)])
def test_a_seed_trained_in_a_group_matches_it_trained_alone_to_rounding(tmp_path, dtype, bound):
    """What the README states: at networks past the bitwise-small ones (64-64, batch 64), agent
    1 of seeds (0, 1) is agent 1 trained alone up to rounding of the batched products."""
    config = AgentConfig(episodes=4, eval_every=4, eval_episodes=2, hidden_sizes=(64, 64),
                         updates_per_episode=10, buffer_size=2000, batch_size=64,
                         warmup_episodes=1)
    group, alone = [tmp_path / "g0", tmp_path / "g1"], [tmp_path / "a1"]
    train(group, seeds=[0, 1], config=config, dtype=dtype)
    train(alone, seeds=[1], config=config, dtype=dtype)
    a, b = (RunFolder(d).load_checkpoint(4)["agent"] for d in (group[1], alone[0]))
    moved = RunFolder(group[0]).load_checkpoint(4)["agent"]
    for net in ("actor", "critic", "actor_target", "critic_target"):
        for key in a[net]:
            assert a[net][key].dtype == dtype
            diff = (a[net][key].double() - b[net][key].double()).abs().max().item()
            assert diff <= bound, (net, key, diff)
            # and seed 0 is another agent: the comparison is not trivially true
            assert not torch.allclose(a[net][key], moved[net][key], atol=1e-3)
