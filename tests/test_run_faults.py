"""Issue 23 on the trainer and its run folders: no silent wrong answer and no lost work under
every fault a resume, a disk or a second process can bring (issue 16's cases are in
test_run_errors.py)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from test_run_errors import TASK, TINY, eval_rows, train
from toy_goal_env import ENV_ID

from ddpg_her.config import AgentConfig
from ddpg_her.multi import MultiTrainer
from ddpg_her.trainer import Trainer

pytestmark = pytest.mark.xdist_group("test_run_faults")
"""Under pytest-xdist one worker runs this module, so that its three runs (`short_run`,
`two_episodes`, `uninterrupted`) are trained once."""

SHORT = AgentConfig(**{**TINY.to_dict(), "episodes": 8, "eval_every": 1, "buffer_size": 60})
"""A checkpoint per episode and a buffer of about two episodes: each checkpoint's window starts
inside an older chunk."""


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
    torch.set_flush_denormal(False)


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> Path:
    """A finished 8-episode run of `SHORT` (checkpoints 7 and 8, chunks 6-8)."""
    path = tmp_path_factory.mktemp("short") / "run"
    train([path], config=SHORT)
    return path


def copy_to(run: Path, dest: Path) -> Path:
    shutil.copytree(run, dest)
    return dest


def corrupt(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:100])


def restored_rows(run: Path) -> torch.Tensor:
    trainer = Trainer(ENV_ID, TASK, SHORT, [0], [str(run)], resume=True, progress=False,
                      tensorboard=False)
    try:
        return trainer.buffer.rows[0, :int(min(trainer.buffer.total[0], SHORT.buffer_size))]
    finally:
        trainer.close()


# --- wrong results and lost work ---------------------------------------------------------------
def test_a_resumed_run_keeps_the_chunks_its_older_checkpoint_needs(tmp_path, short_run):
    """A resume (here of a finished run: nothing to train) used to delete the chunks before the
    latest checkpoint's window, which the older checkpoint still needed: a fallback to it then
    filled the buffer with rows never written, and training died on NaN."""
    resumed = copy_to(short_run, tmp_path / "resumed")
    train([resumed], config=SHORT, resume=True)
    pristine = copy_to(short_run, tmp_path / "pristine")
    for run in (resumed, pristine):
        corrupt(run / "checkpoints" / "episode-000008.pt")
    with pytest.warns(UserWarning, match="older checkpoint of episode 7"):
        a = restored_rows(resumed)
    with pytest.warns(UserWarning, match="older checkpoint of episode 7"):
        b = restored_rows(pristine)
    assert torch.equal(a, b) and bool(torch.isfinite(a).all())
    with pytest.warns(UserWarning, match="older checkpoint of episode 7"):
        train([resumed], config=SHORT, resume=True)
    assert eval_rows(resumed) == eval_rows(short_run)


def test_a_checkpoint_whose_buffer_has_a_gap_is_refused_naming_it(tmp_path, short_run):
    run = copy_to(short_run, tmp_path / "run")
    # the older checkpoint's window starts there
    next((run / "buffer").glob("episode-000006.*npz")).unlink()
    corrupt(run / "checkpoints" / "episode-000008.pt")
    with pytest.warns(UserWarning, match="older checkpoint"), \
            pytest.raises(ValueError, match=rf"{run / 'buffer'}: the checkpoint of episode 7 "
                                            r"needs transitions \d+ to \d+, but no chunk holds"):
        Trainer(ENV_ID, TASK, SHORT, [0], [str(run)], resume=True)


# --- every field given on the command line is the one recorded ----------------------------------
TASK_VALUES = {
    "region": "zmax:0.3", "n_joints": 4, "start_q": [0.0, -0.7, 1.5, 0.0, 0.0, 0.0],
    "base_height": 0.2, "goal_sampler": "cartesian", "control_mode": "velocity",
    "held_joints": "pd", "reward_type": "sparse", "distance_weight": 2, "action_weight": 0.5,
    "action_penalty_unit": "actor", "success_reward": 50, "success_radius": 0.05,
    "terminate_on_success": False, "max_episode_steps": 10, "control_hz": 25, "sim_hz": 2000,
    "kp": [3500.0, 3200.0, 700.0, 200.0, 200.0, 14.0],
    "kd": [250.0, 230.0, 50.0, 15.0, 15.0, 1.0], "gravity_compensation": False,
    "plane_margin": 0.01, "contact_model": "compliant", "contact_stiffness": 100000.0,
    "contact_damping": 1000.0, "contact_friction": 0.5, "contact_max_depth": 0.01,
}
"""A valid value other than the default for each TaskSpec field."""

AGENT_FLAGS = {
    "gamma": (["0.9"], 0.9), "buffer_size": (["500"], 500), "batch_size": (["16"], 16),
    "exploration_rate": (["0.2"], 0.2), "tau": (["0.01"], 0.01),
    "actor_lr": (["0.0002"], 0.0002), "critic_lr": (["0.002"], 0.002),
    "episodes": (["0"], 0), "eval_every": (["7"], 7), "eval_episodes": (["3"], 3),
    "hidden_sizes": (["8", "9"], [8, 9]), "final_init": (["0.001"], 0.001),
    "her_strategy": (["future"], "future"), "her_k": (["2", "--her-strategy", "future"], 2),
    "exploration": (["ou"], "ou"), "ou_theta": (["0.3", "--exploration", "ou"], 0.3),
    "warmup_episodes": (["5"], 5), "updates_per_episode": (["3"], 3),
    "normalize_obs": ([], False), "obs_clip": (["4"], 4.0), "norm_eps": (["0.02"], 0.02),
    "critic_l2": (["0.01"], 0.01), "flush_denormals": ([], False),
    "batch_norm": ([], True), "batch_norm_momentum": (["0.1", "--batch-norm"], 0.1),
    "algo": (["td3"], "td3"),
    "td3_target_noise": (["0.1", "--algo", "td3"], 0.1),
    "td3_target_noise_clip": (["0.3", "--algo", "td3"], 0.3),
    "td3_policy_delay": (["3", "--algo", "td3"], 3),
    "sac_init_alpha": (["0.5", "--algo", "sac"], 0.5),
    "sac_alpha_lr": (["0.001", "--algo", "sac"], 0.001),
    "ensemble": (["2"], 2), "prioritized_replay": ([], True),
    "per_alpha": (["0.5", "--prioritized-replay"], 0.5),
    "per_beta": (["0.5", "--prioritized-replay"], 0.5),
    "per_eps": (["0.001", "--prioritized-replay"], 0.001),
}
"""For each AgentConfig flag, a value other than the default and what spec.json must record
([]: a switch, given as --FLAG where its default is off and as --no-FLAG where it is on)."""


def test_the_tables_name_every_field():
    import dataclasses

    from envs.spec import TaskSpec

    assert set(TASK_VALUES) == {f.name for f in dataclasses.fields(TaskSpec)}
    assert set(AGENT_FLAGS) == {f.name for f in dataclasses.fields(AgentConfig)}


def recorded_spec(tmp_path, *args: str) -> dict:
    import json

    from ddpg_her.train import main

    out = tmp_path / "run"
    assert main([*args, "--episodes", "0", "--out", str(out), "--no-progress",
                 "--no-tensorboard"]) == 0
    return json.loads((out / "spec.json").read_text())


@pytest.mark.parametrize("field", sorted(TASK_VALUES))
def test_every_task_field_given_is_the_one_recorded(tmp_path, field):
    """``--task max_episode_steps=10`` trained 10-step episodes and recorded 100."""
    import json

    value = TASK_VALUES[field]
    flags = ["--region", value] if field == "region" else \
        ["--region", "zheight", "--task", f"{field}={json.dumps(value)}"]
    if field == "goal_sampler":
        flags += ["--task", "n_joints=3"]
    spec = recorded_spec(tmp_path, *flags, "--eval-episodes", "1", "--hidden-sizes", "8", "8")
    recorded = spec["task"][field]
    assert json.dumps(recorded) == json.dumps(value) or recorded == pytest.approx(value)
    if field == "max_episode_steps":
        assert spec["dims"]["max_episode_steps"] == value


@pytest.mark.parametrize("field", sorted(AGENT_FLAGS))
def test_every_agent_flag_given_is_the_one_recorded(tmp_path, field):
    values, expected = AGENT_FLAGS[field]
    switch_off = not values and AgentConfig().to_dict()[field]
    flag = "--" + ("no-" if switch_off else "") + field.replace("_", "-")
    spec = recorded_spec(tmp_path, "--env-id", f"toy_goal_env:{ENV_ID}", "--region", "box",
                         flag, *values)
    default = AgentConfig().to_dict()[field]
    assert spec["agent"][field] == expected != default


def test_a_task_field_the_env_does_not_take_is_refused(tmp_path):
    from ddpg_her.checkpoints import check_recorded

    with pytest.raises(ValueError, match=r"did not take the task field\(s\) given: "
                                         r"max_episode_steps=10 \(the task holds 100\)"):
        check_recorded("UR5Reach-v0", {"max_episode_steps": 10, "start_q": None},
                       {"max_episode_steps": 100, "start_q": [0.0] * 6})


# --- resuming: the recorded budget, lost checkpoints -------------------------------------------
CLI = ["--env-id", f"toy_goal_env:{ENV_ID}", "--region", "box", "--eval-every", "1",
       "--eval-episodes", "2", "--hidden-sizes", "8", "8", "--updates-per-episode", "2",
       "--warmup-episodes", "1", "--no-progress", "--no-tensorboard"]


@pytest.fixture(scope="module")
def two_episodes(tmp_path_factory) -> Path:
    """A finished 2-episode run made by the command line."""
    from ddpg_her.train import main

    out = tmp_path_factory.mktemp("two") / "run"
    assert main([*CLI, "--episodes", "2", "--out", str(out)]) == 0
    return out


def test_resume_without_episodes_keeps_the_recorded_budget_and_says_so(tmp_path, two_episodes,
                                                                       monkeypatch, capsys):
    """The README's ``--resume`` turned a finished 2-episode run into a 20,000-episode plan and
    rewrote its spec.json."""
    from ddpg_her.train import main

    run = copy_to(two_episodes, tmp_path / "run")
    before = {p: (run / p).read_bytes() for p in ("spec.json", "eval.csv")}
    planned = []
    real_run = MultiTrainer.run

    def run_and_note(self):
        planned.append(self.trainers[0].config.episodes)
        return real_run(self) if planned[-1] < 100 else [[t.rows for t in self.trainers]]

    monkeypatch.setattr(MultiTrainer, "run", run_and_note)
    assert main([*CLI, "--out", str(run), "--resume"]) == 0
    assert planned == [2]
    assert "training to the 2 episodes that spec.json records" in capsys.readouterr().err
    assert {p: (run / p).read_bytes() for p in before} == before
    assert main([*CLI, "--out", str(run), "--resume", "--episodes", "3"]) == 0  # given: extends
    assert planned == [2, 3] and len(eval_rows(run)) == 4


def usage_error(capsys, *args: str) -> str:
    from ddpg_her.train import main

    with pytest.raises(SystemExit) as exit_:
        main(list(args))
    assert exit_.value.code == 2
    return capsys.readouterr().err


def test_resume_after_the_checkpoints_were_deleted_is_an_error_naming_the_folder(
        tmp_path, two_episodes, capsys):
    run = copy_to(two_episodes, tmp_path / "run")
    before = (run / "eval.csv").read_bytes()
    shutil.rmtree(run / "checkpoints")
    err = usage_error(capsys, *CLI, "--out", str(run), "--resume", "--episodes", "2")
    assert f"{run} holds a run with 2 test session(s) in eval.csv" in err
    assert f"no checkpoint in {run / 'checkpoints'}" in err and "episode 0" in err
    assert (run / "eval.csv").read_bytes() == before
    assert not (run / "lock.json").exists()


# --- the lock: one trainer per run folder -------------------------------------------------------
@pytest.fixture
def other_process():
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    yield proc.pid
    proc.kill()
    proc.wait()


def ended_pid() -> int:
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def write_lock(run: Path, pid: int) -> None:
    import json
    import socket

    (run / "lock.json").write_text(json.dumps({"pid": pid, "host": socket.gethostname(),
                                               "since": "2026-01-01T00:00:00"}))


def test_a_second_trainer_on_a_folder_is_refused_naming_the_holder(tmp_path, two_episodes,
                                                                   other_process, capsys):
    import socket

    run = copy_to(two_episodes, tmp_path / "run")
    write_lock(run, other_process)
    tmp = run / f".eval.csv.tmp{other_process}"
    tmp.write_text("the other trainer's write in progress")
    before = (run / "spec.json").read_bytes()
    err = usage_error(capsys, *CLI, "--out", str(run), "--resume", "--episodes", "3")
    assert f"{run} is being trained by process {other_process} on host " \
           f"{socket.gethostname()}" in err
    assert tmp.exists() and (run / "spec.json").read_bytes() == before
    assert str(other_process) in (run / "lock.json").read_text()


def test_a_stale_lock_is_taken_over_with_a_warning_and_live_temporary_files_kept(
        tmp_path, two_episodes, other_process):
    from ddpg_her.train import main

    run = copy_to(two_episodes, tmp_path / "run")
    dead = ended_pid()
    write_lock(run, dead)
    live = run / f".eval.csv.tmp{other_process}"
    orphan = run / "checkpoints" / f".episode-000003.pt.tmp{dead}"
    for p in (live, orphan):
        p.write_text("x")
    with pytest.warns(UserWarning, match=rf"taking over the lock of a process that has ended "
                                         rf".*{dead}"):
        main([*CLI, "--out", str(run), "--resume", "--episodes", "3"])
    assert live.exists() and not orphan.exists()
    assert not (run / "lock.json").exists()  # released at the end
    assert len(eval_rows(run)) == 4


# --- file-system faults -------------------------------------------------------------------------
@pytest.fixture
def tmpfs(tmp_path):
    """A mount point for small tmpfs file systems: ``mount(size)``, ``remount(options)``;
    unmounted afterwards. Skipped where mounting is not allowed (not root, a container
    without the capability)."""
    import os
    import subprocess

    point = tmp_path / "mnt"
    point.mkdir()

    def run(*args: str) -> None:
        subprocess.run(["mount", *args], check=True, capture_output=True, timeout=30)

    def mount(size: str) -> Path:
        try:
            run("-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(point))
        except (OSError, subprocess.CalledProcessError) as err:
            pytest.skip(f"cannot mount a tmpfs here ({err}); needs root and CAP_SYS_ADMIN")
        return point

    def remount(options: str) -> None:
        run("-o", f"remount,{options}", str(point))

    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root (a read-only or full disk cannot be "
                    "made otherwise; chmod does not stop root)")
    mount.remount = remount
    yield mount
    subprocess.run(["umount", str(point)], capture_output=True, timeout=30)


def six_episodes(tmp_path_factory) -> Path:
    from ddpg_her.train import main

    out = tmp_path_factory.mktemp("six") / "run"
    assert main([*CLI, "--episodes", "6", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Path:
    """The 6-episode run the fault tests must recover to, trained without a fault."""
    return six_episodes(tmp_path_factory)


@pytest.mark.parametrize("where", ["a file", "under a file"])
def test_an_out_that_cannot_be_a_folder_is_a_usage_error_naming_it(tmp_path, capsys, where):
    blocker = tmp_path / "blocker"
    blocker.write_text("not a folder")
    out = blocker if where == "a file" else blocker / "run"
    err = usage_error(capsys, *CLI, "--episodes", "2", "--out", str(out))
    assert f"cannot create the folder {out}" in err or f"cannot create {out}" in err, err
    assert "Traceback" not in err and blocker.read_text() == "not a folder"


def test_a_read_only_out_is_refused_before_any_training(tmpfs, capsys):
    root = tmpfs("1m")
    tmpfs.remount("ro")
    err = usage_error(capsys, *CLI, "--episodes", "2", "--out", str(root / "run"))
    assert f"cannot create the folder {root / 'run'}: Read-only file system" in err, err


def test_a_folder_made_read_only_midway_stops_clearly_and_resumes_exactly(
        tmpfs, capsys, monkeypatch, uninterrupted):
    from ddpg_her.runfolder import RunFolder
    from ddpg_her.train import main

    root = tmpfs("1m")
    saved = []
    real = RunFolder.save_checkpoint

    def save_then_freeze(self, episode, state, keep=2):
        real(self, episode, state, keep)
        saved.append(episode)
        if episode == 3:
            tmpfs.remount("ro")

    monkeypatch.setattr(RunFolder, "save_checkpoint", save_then_freeze)
    with pytest.raises(SystemExit) as exit_:
        main([*CLI, "--episodes", "6", "--out", str(root / "run")])
    err = capsys.readouterr().err
    assert exit_.value.code == 1 and "Read-only file system" in err and str(root / "run") in err
    assert "--resume" in err and "Traceback" not in err
    tmpfs.remount("rw")
    assert main([*CLI, "--episodes", "6", "--out", str(root / "run"), "--resume"]) == 0
    assert eval_rows(root / "run") == eval_rows(uninterrupted)
    assert not [p for p in (root / "run").rglob(".*.tmp*")]


def test_a_full_disk_stops_clearly_leaves_nothing_half_written_and_resumes_exactly(
        tmpfs, capsys, uninterrupted):
    from ddpg_her.train import main

    root = tmpfs("64k")  # a checkpoint is about 32 KB: the second does not fit
    with pytest.raises(SystemExit) as exit_:
        main([*CLI, "--episodes", "6", "--out", str(root / "run")])
    err = capsys.readouterr().err
    assert exit_.value.code == 1 and "No space left on device" in err, err
    assert not [p for p in (root / "run").rglob(".*.tmp*")]  # no partial file left
    tmpfs.remount("size=2m")
    assert main([*CLI, "--episodes", "6", "--out", str(root / "run"), "--resume"]) == 0
    assert eval_rows(root / "run") == eval_rows(uninterrupted)


def test_a_finished_run_on_a_read_only_folder_is_read_and_reported(tmpfs, capsys,
                                                                   uninterrupted):
    from ddpg_her.runfolder import read_run
    from ddpg_her.summary import main as summary

    root = tmpfs("1m")
    run = copy_to(uninterrupted, root / "run")
    tmpfs.remount("ro")
    assert read_run(run).finished
    assert summary([str(run)]) in (0, None)
    assert str(run) in capsys.readouterr().out
    err = usage_error(capsys, *CLI, "--episodes", "7", "--out", str(run), "--resume")
    assert f"cannot create {run / 'lock.json'}: Read-only file system" in err, err


# --- killed at random moments -------------------------------------------------------------------
def _train_in_child(args: list[str]) -> None:
    import os
    import sys

    from ddpg_her.train import main

    sys.stderr = open(os.devnull, "w")  # noqa: SIM115 (the warnings of a taken-over lock)
    code = main(args)
    os._exit(code or 0)


def test_a_run_killed_at_random_moments_resumes_to_the_uninterrupted_eval_csv(tmp_path,
                                                                              uninterrupted):
    """SIGKILL at seeded random moments (opening the folder, training, a chunk, checkpoint or
    eval.csv write), each time resumed: eval.csv ends as the uninterrupted run's, and no
    temporary file or lock is left. The trainer runs in a forked child of this process, so
    a start costs no imports."""
    import multiprocessing
    import random
    import time

    fork = multiprocessing.get_context("fork")

    def start(out: Path, resume: bool):
        args = [*CLI, "--episodes", "6", "--out", str(out), *(["--resume"] if resume else [])]
        child = fork.Process(target=_train_in_child, args=(args,))
        child.start()
        return child

    # The moments are drawn as fractions of this machine's own uninterrupted run (a fast CI
    # machine trains the 6 episodes in under 0.4 s): each kill comes before a quarter of a
    # whole run has passed, so the first three tries cannot finish.
    began = time.perf_counter()
    whole = start(tmp_path / "whole", resume=False)
    whole.join(timeout=120)
    span = time.perf_counter() - began
    assert whole.exitcode == 0 and eval_rows(tmp_path / "whole") == eval_rows(uninterrupted)
    out = tmp_path / "run"
    rng = random.Random(23)
    kills = 0
    for attempt in range(12):
        child = start(out, resume=out.exists())
        child.join(timeout=rng.uniform(0.01, 0.25) * span if attempt < 6 else 120)
        if child.exitcode is None:
            child.kill()
            child.join()
            kills += 1
            continue
        assert child.exitcode == 0
        break
    assert kills >= 3  # most tries were cut short
    assert eval_rows(out) == eval_rows(uninterrupted)
    assert not (out / "lock.json").exists() and not list(out.rglob(".*.tmp*"))


# --- sizes that cannot fit, runs that diverge ---------------------------------------------------
@pytest.mark.parametrize("flag, values", [("--buffer-size", ["10000000000000"]),
                                          ("--hidden-sizes", ["1000000", "1000000"])])
def test_sizes_that_cannot_fit_are_refused_up_front_naming_the_flag(tmp_path, capsys, flag,
                                                                    values):
    err = usage_error(capsys, *CLI, "--episodes", "2", flag, *values, "--out",
                      str(tmp_path / "run"))
    assert f"error: {flag}: 1 agent(s) would need" in err and "GiB available on cpu" in err, err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("replay", [[], ["--prioritized-replay"]])
def test_a_diverging_run_says_it_diverged_and_keeps_its_last_finite_checkpoint(tmp_path,
                                                                               capsys, replay):
    """With learning rates of 1e38 the networks turn NaN in the first updates; the run wrote
    NaN eval rows to the end and exited 0 (with prioritized replay, whose losses were never
    added up, until 2026-11-29)."""
    from ddpg_her.train import main

    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exit_:
        main([*CLI, "--episodes", "6", "--out", str(out), "--critic-lr", "1e38",
              "--actor-lr", "1e38", *replay])
    err = capsys.readouterr().err
    assert exit_.value.code == 1
    assert f"the networks diverged (a loss is not finite) in training episode 2: seed 0 " \
           f"({out}): critic loss nan" in err, err
    rows = eval_rows(out)
    assert len(rows) == 2 and "nan" not in rows[1]
    state = torch.load(out / "checkpoints" / "episode-000001.pt", weights_only=True)
    assert all(bool(torch.isfinite(v).all()) for v in state["agent"]["actor"].values())


# --- every field by kind: ranges, NaN, types; spec.json as strictly as the command line ---------
BAD_AGENT_VALUES = {
    **{name: [float("nan"), True, "0.5"] for name in (
        "gamma", "exploration_rate", "tau", "actor_lr", "critic_lr", "final_init", "ou_theta",
        "obs_clip", "norm_eps", "critic_l2", "batch_norm_momentum", "td3_target_noise",
        "td3_target_noise_clip", "sac_init_alpha", "sac_alpha_lr", "per_alpha", "per_beta",
        "per_eps")},
    **{name: [float("nan"), 10.5, True, "10"] for name in (
        "buffer_size", "batch_size", "episodes", "eval_every", "eval_episodes", "her_k",
        "warmup_episodes", "updates_per_episode", "td3_policy_delay", "ensemble")},
    "hidden_sizes": ["12", [400.5, 300], [400, True], [400], None],
    "normalize_obs": ["false", 0, None],
    "flush_denormals": ["true", 1, None],
    "batch_norm": ["true", 1, None],
    "prioritized_replay": ["true", 1, None],
    "algo": ["ddgp", 1],
    "her_strategy": ["finale", 1],
    "exploration": ["gauss", None],
}
"""For each AgentConfig field, values of the wrong kind: NaN, a bool or a string for a number,
a float for a count, a string or floats for the two sizes, text for a switch."""


def test_every_agent_field_has_bad_values():
    import dataclasses

    assert set(BAD_AGENT_VALUES) == {f.name for f in dataclasses.fields(AgentConfig)}


@pytest.mark.parametrize("field, value", [(f, v) for f, vs in BAD_AGENT_VALUES.items()
                                          for v in vs])
def test_every_agent_field_refuses_values_of_the_wrong_kind(field, value):
    with pytest.raises(ValueError, match=rf"invalid agent configuration: (.*, )?{field}="):
        AgentConfig(**{field: value})
    with pytest.raises(ValueError, match=rf"invalid agent configuration: (.*, )?{field}="):
        AgentConfig.from_dict({**AgentConfig().to_dict(), field: value})  # as spec.json


@pytest.mark.parametrize("field, value", [("hidden_sizes", "16"), ("gamma", float("nan")),
                                          ("normalize_obs", "false")])
def test_a_policy_whose_spec_json_is_invalid_is_refused_naming_it(tmp_path, two_episodes,
                                                                  field, value):
    import json

    import ddpg_her

    run = copy_to(two_episodes, tmp_path / "run")
    spec = json.loads((run / "spec.json").read_text())
    spec["agent"][field] = value
    (run / "spec.json").write_text(json.dumps(spec))
    with pytest.raises(ValueError, match=rf"{run / 'spec.json'} does not hold a valid run "
                                         rf"specification .*{field}="):
        ddpg_her.load(run)


@pytest.mark.parametrize("change, message", [
    (lambda o: {k: v for k, v in o.items() if k != "desired_goal"}, "keys"),
    (lambda o: {**o, "observation": o["observation"][:-1]}, "obs['observation'] must be"),
    (lambda o: {**o, "desired_goal": np.full_like(o["desired_goal"], np.nan)},
     "obs['desired_goal'] must be finite"),
    (lambda o: {**o, "achieved_goal": "0 0"}, "obs['achieved_goal'] must be"),
    (lambda o: {**o, "achieved_goal": np.stack([o["achieved_goal"]] * 2)},
     "must share their batch shape"),
    (lambda o: [o["observation"]], "obs must be the env's Dict observation"),
])
def test_a_trained_policy_refuses_observations_it_cannot_use(two_episodes, change, message):
    import gymnasium

    import ddpg_her

    policy = ddpg_her.load(two_episodes)
    env = gymnasium.make(ENV_ID, **policy.spec["env_kwargs"])  # (make_env passes task=, which
    obs, _ = env.reset(seed=0)                                # the toy env does not take)
    assert policy(obs).shape == env.action_space.shape
    with pytest.raises(ValueError, match=re.escape(message)):
        policy(change(obs))


# --- flags that contradict each other -----------------------------------------------------------
@pytest.mark.parametrize("flags, message", [
    (["--her-k", "8"], "--her-k has no effect with --her-strategy final"),
    (["--her-k", "8", "--her-strategy", "none"], "--her-k has no effect with --her-strategy none"),
    (["--ou-theta", "0.3"], "--ou-theta has no effect with --exploration gaussian"),
    (["--obs-clip", "3", "--no-normalize-obs"], "--obs-clip has no effect with "
                                                "--no-normalize-obs"),
    (["--norm-eps", "0.1", "--no-normalize-obs"], "--norm-eps has no effect with "
                                                  "--no-normalize-obs"),
    (["--eval-every", "2", "--episodes", "5"], "--episodes 5 is not a multiple of --eval-every 2"
                                               ": its last 1 episode(s) would have no test"),
])
def test_flags_that_contradict_each_other_are_a_usage_error(tmp_path, capsys, flags, message):
    """Each was accepted: the flag silently did nothing, or the run never counted as
    finished (a sweep would resume it for ever)."""
    err = usage_error(capsys, *CLI, *flags, "--out", str(tmp_path / "run"))
    assert message in err, err
    assert not (tmp_path / "run").exists()


def test_flags_that_agree_are_accepted(tmp_path):
    spec = recorded_spec(tmp_path, "--env-id", f"toy_goal_env:{ENV_ID}", "--region", "box",
                         "--her-k", "2", "--her-strategy", "future", "--ou-theta", "0.3",
                         "--exploration", "ou")
    assert spec["agent"]["her_k"] == 2 and spec["agent"]["ou_theta"] == 0.3


@pytest.mark.parametrize("content", ["garbage", "", '{"pid": "x"}', "[1, 2]"])
def test_a_garbage_lock_is_named_as_such_not_as_process_none(tmp_path, content):
    """Issue 37, kind 6: an unreadable lock.json said 'process None on host None'."""
    from ddpg_her.runfolder import RunFolder, RunFolderBusy

    folder = RunFolder(tmp_path / "run")
    (tmp_path / "run").mkdir()
    folder.lock_path.write_text(content)
    with pytest.raises(RunFolderBusy) as err:
        folder.lock()
    message = str(err.value)
    assert "None" not in message and f"{folder.lock_path} is not a lock this code wrote" in \
        message and repr(content) in message, message
    assert folder.lock_path.read_text() == content  # left for its owner or a person


@pytest.mark.parametrize("device", ["nosuch", "cpu:x", 3])
def test_load_refuses_a_device_that_is_not_torch_s_in_our_words(tmp_path, device):
    """Issue 37, kind 4 (found by benchmarks/reliability_probe.py): ``ddpg_her.load(run,
    device="nosuch")`` ended in torch's RuntimeError listing its device types; the check runs
    before the folder is read, so a missing folder is not needed to see it."""
    import ddpg_her

    with pytest.raises(ValueError, match=rf"device must be a torch device string .*got "
                                         rf"{device!r}"):
        ddpg_her.load(tmp_path / "nosuch", device=device)
