"""Issue 41: one gate for every input. The training program checked like the other paths (memory
before allocating, resume comparing every recorded field, dry runs refusing what the real run
refuses), a unit's own arguments never overridden, writers that do not replace finished work,
values outside their range refused, and one-line errors.

Each test runs the entry point a person types (its ``main``) or the library call, and compares
with an independent reference: what the other path says, what the real run does, the measured
bytes of a test copy.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import pytest
import torch
import trimesh

from ddpg_her import agents, train, train_many
from ddpg_her.config import AgentConfig
from ddpg_her.runfolder import RunFolder

TINY = ["--episodes", "2", "--eval-every", "2", "--eval-episodes", "2", "--hidden-sizes", "8",
        "8", "--updates-per-episode", "2", "--warmup-episodes", "1", "--batch-size", "8",
        "--buffer-size", "400"]


def run_main(main, argv):
    """(exit status, stderr) of ``main(argv)``; SystemExit's code, 0 for a return of 0."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exit_:
            code = exit_.code
    return code, err.getvalue()


def error_line(text):
    """The refusal: the last line of a usage error's output."""
    return text.strip().splitlines()[-1]


@pytest.fixture
def eight_gib(monkeypatch):
    """A device of 8 GiB available memory, whatever this machine has free."""
    monkeypatch.setattr(agents, "available_memory", lambda device: 8 * 2 ** 30)


# ---------------------------------------------------------------------------- kind 1
@pytest.mark.parametrize(("flags", "named"), [
    (["--eval-episodes", "100000"], "--eval-episodes"),
    (["--buffer-size", str(10 ** 9)], "--buffer-size"),
    (["--hidden-sizes", "100000", "100000"], "--hidden-sizes"),
])
def test_the_program_estimates_memory_before_allocating(tmp_path, eight_gib, flags, named):
    """The issue's three: 100,000 test copies at the measured ~196 kB each are ~19.6 GB (the
    issue saw 19.5 GB before the kernel killed the run); 1e9 transitions x 50 float32 = 200 GB;
    two 1e5 layers = 1e10 weights. All refused in one line naming the flag, nothing written;
    the numpy backend's refusal of the same flag names the same flag."""
    out = tmp_path / "run"
    argv = ["--region", "farbox", "--out", str(out), "--no-progress", "--no-tensorboard",
            *flags]
    code, err = run_main(train.main, [*argv, "--env-backend", "program"])
    assert code == 2, err
    assert named in error_line(err) and "GiB" in error_line(err)
    assert not out.exists()
    if named != "--eval-episodes":  # the host envs are made before the numpy path checks
        code_numpy, err_numpy = run_main(train.main, argv)
        assert code_numpy == 2 and named in error_line(err_numpy)


def test_the_test_copies_estimate_is_the_measured_one(eight_gib):
    """100 test episodes (the paper's) pass, 100,000 do not: the estimate is 250 kB a copy, an
    upper bound of the 196 kB measured (program.TEST_COPY_BYTES's command)."""
    from ddpg_her.program import check

    task = [dict(region="farbox", n_joints=3)]
    check("UR5Reach-v0", task, AgentConfig(eval_episodes=100))
    with pytest.raises(ValueError, match="--eval-episodes: 1 agent"):
        check("UR5Reach-v0", task, AgentConfig(eval_episodes=100_000))
    # 30,000 copies: 7.5 GB estimated, under 8 GiB; with 2 agents, over
    check("UR5Reach-v0", task, AgentConfig(eval_episodes=30_000))
    with pytest.raises(ValueError, match="--eval-episodes: 2 agent"):
        check("UR5Reach-v0", task * 2, AgentConfig(eval_episodes=30_000))


def mesh_region(tmp_path):
    stl = tmp_path / "goal.stl"
    trimesh.creation.box(bounds=[[0.4, -0.1, 0.1], [0.6, 0.1, 0.3]]).export(stl)
    return f"mesh:{stl}"


PROGRAM_REFUSALS = [
    (["--algo", "td3"], "--algo td3"),
    (["--algo", "sac"], "--algo sac"),
    (["--batch-norm"], "--batch-norm"),
    (["--her-strategy", "future"], "--her-strategy future"),
    (["--task", "contact_model=compliant"], "contact_model='compliant'"),
    (["--task", "held_joints=dynamic"], "held_joints"),
]


def program_refusals(tmp_path):
    return [*PROGRAM_REFUSALS, (["--region", mesh_region(tmp_path)], "mesh")]


@pytest.mark.parametrize("case", range(len(PROGRAM_REFUSALS) + 1))
def test_dry_runs_refuse_what_the_program_refuses_with_its_cause(tmp_path, case):
    """train_many --dry-run and sweep --program --dry-run refuse each unit the real program
    run refuses, with the same cause (the reference: the real train_many run's refusal)."""
    from analysis import sweep

    flags, cause = program_refusals(tmp_path)[case]
    region = flags[1] if flags[0] == "--region" else "farbox"
    unit_flags = [] if flags[0] == "--region" else flags
    unit = f"--region {region} --out {tmp_path / 'u'} " + " ".join(
        f"'{f}'" for f in [*unit_flags, *TINY])
    real_code, real_err = run_main(train_many.main, ["--unit", unit, "--env-backend", "program",
                                                     "--no-progress"])
    assert real_code == 2 and cause in error_line(real_err), real_err
    code, err = run_main(train_many.main, ["--unit", unit, "--env-backend", "program",
                                           "--dry-run"])
    assert code == 2 and cause in error_line(err), err
    assert error_line(err) == error_line(real_err)
    if flags[0] != "--region":
        code, err = run_main(sweep.main, ["--setting", "farbox:3", "--seeds", "1", "--out",
                                          str(tmp_path / "sweep"), "--program", "--dry-run",
                                          "--", *unit_flags])
        assert code == 2 and cause in err, err
    assert not (tmp_path / "u").exists() and not (tmp_path / "sweep").exists()


@pytest.mark.parametrize("backend", ["numpy", "batched"])
def test_a_dry_run_of_one_unit_refuses_its_task_as_the_real_run_does(tmp_path, backend):
    """The reference is the real run's refusal: a single unit's dry run had listed a unit with
    an unknown region (grouping one unit built no env)."""
    unit = f"--region nowhere --out {tmp_path / 'u'}"
    real_code, real_err = run_main(train_many.main, ["--unit", unit, "--env-backend", backend])
    code, err = run_main(train_many.main, ["--unit", unit, "--env-backend", backend,
                                           "--dry-run"])
    assert real_code == code == 2 and "nowhere" in error_line(real_err), real_err
    assert "nowhere" in error_line(err) and not (tmp_path / "u").exists(), err


def test_tf32_on_the_cpu_and_cuda_without_a_device_refused_by_dry_runs(tmp_path, monkeypatch):
    from analysis import sweep

    unit = f"--region farbox --out {tmp_path / 'u'}"
    code, err = run_main(train_many.main, ["--unit", unit, "--env-backend", "program",
                                           "--tf32", "--dry-run"])
    assert code == 2 and "--tf32 is a CUDA setting" in error_line(err)
    code, err = run_main(sweep.main, ["--setting", "farbox:3", "--out", str(tmp_path / "s"),
                                      "--program", "--tf32", "--dry-run"])
    assert code == 2 and "--tf32 is a CUDA setting" in err
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    for main, argv in ((train_many.main, ["--unit", unit, "--device", "cuda"]),
                       (sweep.main, ["--setting", "farbox:3", "--out", str(tmp_path / "s"),
                                     "--device", "cuda", "--program"])):
        code, err = run_main(main, argv)  # the real run refuses
        assert code == 2 and "no CUDA device" in err, err
        # the dry run flags it (a GPU run is planned on another machine) and lists the units
        code, err = run_main(main, [*argv, "--dry-run"])
        assert code == 0 and "note: --device cuda: no CUDA device" in err, err


def test_a_failed_sweep_process_prints_its_cause(tmp_path):
    from analysis import sweep

    log = tmp_path / "x.log"
    log.write_text("starting\nerror: --tf32 is a CUDA setting\n\n")
    assert sweep.failure(log).startswith("error: --tf32 is a CUDA setting (whole log: ")
    assert sweep.failure(tmp_path / "none.log").startswith("it wrote nothing")


def tiny_program_run(tmp_path, name="run"):
    from ddpg_her.program import Program
    from tests.test_program import FirstOrderArm

    config = AgentConfig(hidden_sizes=(8, 8), warmup_episodes=1, eval_every=2, eval_episodes=2,
                         updates_per_episode=2, batch_size=8, buffer_size=400, episodes=2)
    return lambda episodes=2, resume=False: Program(
        "UR5Reach-v0", [dict(region="farbox", n_joints=3)],
        AgentConfig(**{**config.to_dict(), "episodes": episodes}), [0], [tmp_path / name],
        resume=resume, progress=False, dynamics=FirstOrderArm)


@pytest.mark.parametrize("edit", ["tf32", "removed", "streams"])
def test_resume_compares_the_program_section(tmp_path, edit):
    """A run recorded as TF32 does not resume in float32; an edited or removed section is
    refused naming it. The unedited run resumes (the reference)."""
    make = tiny_program_run(tmp_path)
    program = make()
    program.run()
    program.close()
    make(4, resume=True).close()  # unedited: resumes
    folder = RunFolder(tmp_path / "run")
    spec = folder.read_spec()
    if edit == "tf32":
        spec["program"]["matmul"] = "tf32"
    elif edit == "removed":
        del spec["program"]
    else:
        spec["program"]["streams"] = "mix32-counter-0"
    folder.spec_path.write_text(json.dumps(spec))
    with pytest.raises(ValueError, match=r"differing: program \(was"):
        make(4, resume=True)
    # the checkpoint records the section too: a spec.json put back by hand is checked by it
    assert folder.load_checkpoint(2)["config"]["program"]["matmul"] == "float32"


# ---------------------------------------------------------------------------- kind 2
@pytest.mark.parametrize(("unit", "after"), [
    ("--region farbox", ["--region", "zheight"]),
    ("--region farbox --out OUT", ["--out", "elsewhere"]),
    ("--region farbox --seeds 0 1", ["--seeds", "3", "4"]),
    ("--region farbox --seed 0", ["--seeds", "3", "4"]),
    ("--region farbox --joints 3", ["--joints", "6"]),
    ("--region farbox --episodes 4", ["--episodes", "8"]),
    ("--region farbox --joints 3", ["--joi", "6"]),  # an abbreviation argparse resolves
])
def test_arguments_after_dashes_never_replace_a_units_own(tmp_path, unit, after):
    """Appended, the last flag won (argparse's rule, the reference): the unit trained what the
    -- arguments said. Refused, naming the flag; a flag the unit lacks is still appended."""
    unit = unit.replace("OUT", str(tmp_path / "mine"))
    code, err = run_main(train_many.main, ["--unit", unit, "--dry-run", "--", *after])
    assert code == 2 and after[0] in error_line(err) and "never overridden" in error_line(err)
    parsed = train.parse_args(train.make_parser(), [*unit.split(), *after])
    dest = {"--joi": "joints", "--seeds": "seeds"}.get(after[0], after[0][2:])
    assert str(getattr(parsed, dest)).strip("[]'").replace("'", "").replace(",", "") == \
        " ".join(after[1:])  # what the old appending trained
    code, err = run_main(train_many.main, ["--unit", f"--region farbox --out {tmp_path / 'x'}",
                                           "--dry-run", "--", "--episodes", "200"])
    assert code == 0, err


@pytest.mark.parametrize("flag", [["--env-backend", "numpy"], ["--device", "cpu"],
                                  ["--threads", "1"], ["--no-progress"]])
def test_a_units_process_flag_is_refused_even_at_the_default(tmp_path, flag):
    """A unit's own --env-backend numpy was ignored under --env-backend program (its value
    equals the default, so the old check compared values and saw nothing)."""
    unit = f"--region farbox --out {tmp_path / 'u'} " + " ".join(flag)
    code, err = run_main(train_many.main, ["--unit", unit, "--env-backend", "program",
                                           "--dry-run"])
    assert code == 2 and flag[0] in error_line(err) and "process flag" in error_line(err)


@pytest.mark.parametrize("unit_args", ["--region zheight", "--seeds 3 4", "--out x",
                                       "--episodes 5", "--hidden-sizes 8 8 'unbalanced"])
def test_grid_episode_refuses_unit_args_that_change_the_grid(unit_args):
    from benchmarks import grid_episode

    code, err = run_main(grid_episode.main, ["--device", "cpu", "--part", "2", "--unit-args",
                                             unit_args])
    assert code == 2, err
    line = error_line(err)
    assert (unit_args.split()[0] in line and "never overridden" in line) or \
        "cannot be split" in line, line
    assert "Traceback" not in err


# ---------------------------------------------------------------------------- kinds 3 and 4
def test_the_default_folder_names_the_algorithm_and_task_overrides():
    """The README's TD3 and compliant lines landed in the plain lines' folders."""
    parser = train.make_parser()
    dirs = [train.request(train.parse_args(parser, a)).run_dirs[0] for a in (
        ["--region", "farbox"], ["--region", "farbox", "--algo", "td3"],
        ["--region", "zheight"], ["--region", "zheight", "--task", "contact_model=compliant"])]
    assert dirs == ["runs/farbox-j3-s0", "runs/farbox-j3-algo=td3-s0", "runs/zheight-j3-s0",
                    "runs/zheight-j3-contact_model=compliant-s0"]


def test_seeds_over_a_single_seed_folder_refused(tmp_path):
    """--seeds 0 1 --resume over OUT holding seed 0's run trained seed 0 again in OUT/s0."""
    out = tmp_path / "one"
    RunFolder(out).write_spec({"format": "x", "seed": 0})
    code, err = run_main(train.main, ["--region", "farbox", "--out", str(out), "--seeds", "0",
                                      "1", "--resume", *TINY])
    assert code == 2 and "holds a run of one seed" in error_line(err)
    assert sorted(p.name for p in out.iterdir()) == ["spec.json"]


@pytest.mark.parametrize("out", ["", " ", "x" * 300])
def test_an_empty_or_overlong_out_refused_in_one_line(tmp_path, out):
    code, err = run_main(train.main, ["--region", "farbox", "--out", out, *TINY])
    assert code == 2 and "--out" in error_line(err) and "Traceback" not in err


def test_collect_does_not_replace_other_runs_without_force(tmp_path):
    """The README's --collect results/sensitivity replaced committed 1,000-episode runs with
    100-episode ones. Now refused naming them, nothing written; --force replaces; collecting
    the same runs again is fine."""
    from analysis import sensitivity as sens
    from tests.test_sensitivity import _write_run

    root, dest = tmp_path / "runs", tmp_path / "dest"
    argv = ["--collect", str(dest), "--out", str(root), "--seeds", "1", "--readings", "ours",
            "--setting", "zheight:3"]
    _write_run(root / "ours" / "zheight-j3" / "s0", "zheight", 3, 0, 40.0)
    assert run_main(sens.main, argv)[0] == 0
    first = (dest / "runs/ours/zheight-j3/s0/eval.csv").read_bytes()
    assert run_main(sens.main, argv)[0] == 0  # the same runs: nothing to replace
    shutil.rmtree(root)
    _write_run(root / "ours" / "zheight-j3" / "s0", "zheight", 3, 0, 90.0)
    code, err = run_main(sens.main, argv)
    assert code == 2 and "would replace 1 file(s)" in err and "eval.csv" in err
    assert (dest / "runs/ours/zheight-j3/s0/eval.csv").read_bytes() == first
    assert run_main(sens.main, [*argv, "--force"])[0] == 0
    assert (dest / "runs/ours/zheight-j3/s0/eval.csv").read_bytes() == \
        (root / "ours/zheight-j3/s0/eval.csv").read_bytes() != first


def test_a_report_does_not_replace_another_without_force(tmp_path):
    from analysis import sensitivity as sens
    from tests.test_sensitivity import _write_run

    root, out = tmp_path / "runs", tmp_path / "report"
    for seed in range(2):
        _write_run(root / "ours" / "zheight-j3" / f"s{seed}", "zheight", 3, seed, 40.0 + seed)
    argv = ["report", str(root), "--out", str(out), "--worth-goals", "0", "--reps", "50",
            "--seeds", "2"]
    assert run_main(sens.main, argv)[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert run_main(sens.main, argv)[0] == 0  # the same report again
    code, err = run_main(sens.main, [*argv, "--episodes", "500"])
    assert code == 2 and "would replace" in err and "--force" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert run_main(sens.main, [*argv, "--episodes", "500", "--force"])[0] == 0
    assert (out / "report.md").read_bytes() != before["report.md"]


# ---------------------------------------------------------------------------- kinds 5, 6 and 7
def test_an_epsilon_rate_is_a_probability():
    """With --exploration epsilon, nu is the probability of a random action (config's own
    docstring): 1.5 was accepted. As Gaussian noise's std it may exceed 1."""
    with pytest.raises(ValueError, match=r"exploration_rate=1.5 .*probability"):
        AgentConfig(exploration="epsilon", exploration_rate=1.5)
    AgentConfig(exploration="epsilon", exploration_rate=1.0)
    AgentConfig(exploration="gaussian", exploration_rate=1.5)


def test_threads_beyond_the_cores_refused(tmp_path):
    import os

    code, err = run_main(train.main, ["--region", "farbox", "--out", str(tmp_path / "r"),
                                      "--threads", "10000", *TINY])
    assert code == 2 and f"1..{os.cpu_count()}" in error_line(err)
    assert not (tmp_path / "r").exists()


def test_load_names_a_non_integer_episode(tiny_ur5_run):
    import ddpg_her

    with pytest.raises(ValueError, match=r"episode must be an integer .* got '2'"):
        ddpg_her.load(tiny_ur5_run, episode="2")


def test_start_after_in_a_missing_folder_refused_at_once(tmp_path):
    from benchmarks import grid_episode

    code, err = run_main(grid_episode.main, ["--device", "cpu", "--part", "2", "--start-after",
                                             str(tmp_path / "no" / "such" / "file")])
    assert code == 2 and "does not exist" in error_line(err)


def test_ur5kin_refuses_what_is_not_a_position_or_angle():
    import numpy as np

    import ur5kin

    with pytest.raises(ValueError, match="could not convert"):
        ur5kin.wrap("x")
    assert ur5kin.wrap(3 * np.pi) == pytest.approx(np.pi)
    with pytest.raises(ValueError, match="NaN"):
        ur5kin.to_base([np.nan, 0.0, 0.0], 0.0)
    with pytest.raises(ValueError, match="shape"):
        ur5kin.to_base([0.0, 0.0], 0.0)
    assert ur5kin.to_base([0.1, 0.2, 0.5], 0.3).tolist() == pytest.approx([0.1, 0.2, 0.2])


def test_ctrl_c_of_a_sweep_ends_with_its_line_not_a_traceback(tmp_path, monkeypatch):
    from analysis import sweep

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep, "run_one_process", interrupted)
    monkeypatch.setattr(sweep, "run_local", interrupted)
    for flags in (["--program"], []):
        code, err = run_main(sweep.main, ["--setting", "farbox:3", "--seeds", "1", "--out",
                                          str(tmp_path / "sw"), *flags])
        assert code == 130 and "Traceback" not in err


# ---------------------------------------------------------------------------- kind 7
COMMANDS = sorted(f"{p.parent.name}.{p.stem}" for package in ("ddpg_her", "analysis")
                  for p in (Path(__file__).parents[1] / package).glob("*.py")
                  if "= Parser(" in p.read_text())


@pytest.mark.parametrize("module", COMMANDS)
def test_a_usage_error_is_one_line(module):
    """Every command's usage error is one line naming the bad flag (argparse's own parser, the
    reference, prints the usage first: for ddpg_her.train about 35 lines)."""
    import importlib

    code, err = run_main(importlib.import_module(module).main, ["--no-such-flag-41"])
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "--help" in err and ("--no-such-flag-41" in err or "required" in err), err


# ---------------------------------------------------------------------------- kind 5
def test_the_program_records_a_subnormal_start_angle_as_typed(tmp_path):
    """The program set the CPU's subnormal flush before writing spec.json, and the flush reaches
    Python's floats: a start_q entry of 1e-320 was recorded as 0.0. The reference is the typed
    value (the numpy trainer's record, tests/test_ddpg_train.py)."""
    from ddpg_her.program import Program
    from tests.test_program import FirstOrderArm

    start = (1e-320, -0.785, 1.57, 0.0, 0.0, 0.0)
    config = AgentConfig(hidden_sizes=(8, 8), warmup_episodes=1, eval_every=2, eval_episodes=2,
                         updates_per_episode=2, batch_size=8, buffer_size=400, episodes=2)
    try:
        Program("UR5Reach-v0", [dict(region="farbox", n_joints=3, start_q=start)], config, [0],
                [tmp_path / "r"], progress=False, dynamics=FirstOrderArm).close()
    finally:
        torch.set_flush_denormal(False)  # json.loads under the flush reads 1e-320 as 0.0 too
    spec = json.loads((tmp_path / "r" / "spec.json").read_text())
    assert tuple(spec["task"]["start_q"]) == start and spec["task"]["start_q"][0] > 0


@pytest.mark.parametrize("name", ["farbox", "closebox", "zheight", "box:0.5,0.9,-0.4,0.4,0,0.4"])
@pytest.mark.parametrize("height", [-1.0, float("nan"), float("inf"), "0.1"])
def test_a_region_refuses_the_base_height_a_task_refuses(name, height):
    """regions.get('farbox', base_height=-1) was accepted (a box does not use the height);
    TaskSpec, the reference, refuses the same heights: both now through one description."""
    import regions
    from envs.spec import TaskSpec

    for build in (lambda: regions.parse(name, height), lambda: TaskSpec(base_height=height),
                  *([lambda: regions.get(name, base_height=height)] * (":" not in name))):
        with pytest.raises(ValueError, match=r"base_height=.* \(expected a finite number >= 0"):
            build()


def test_success_maps_default_slice_outside_the_region_suggests_a_z_inside(tiny_ur5_run,
                                                                           tmp_path):
    """The default slice (0.7-0.8 m) misses the far box (z in [0, 0.4] m) and the refusal never
    said --z; the suggested slice, the reference, then draws a map."""
    import re

    from analysis import success_map

    out = ["--goals", "20", "--out", str(tmp_path / "map.png"), "--no-progress"]
    code, err = run_main(success_map.main, [str(tiny_ur5_run), *out])
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    z = re.search(r"try --z (\S+) (\S+)", err)
    assert z and "[0, 0.4] m" in err, err
    assert 0.0 <= float(z[1]) < float(z[2]) <= 0.4
    assert run_main(success_map.main, [str(tiny_ur5_run), *out, "--z", z[1], z[2]])[0] == 0
    assert (tmp_path / "map.png").exists()


@pytest.mark.parametrize(("field", "value"), [("n_joints", 9), ("base_height", -1),
                                              ("region", "nowhere")])
def test_readers_refuse_a_recorded_task_outside_its_description(tiny_ur5_run, tmp_path, field,
                                                                value):
    """analysis.curves drew a spec.json saying 9 joints; a reader now reads the recorded task
    through TaskSpec, the same description the trainer wrote it from. The unedited copy, the
    reference, is drawn."""
    from analysis import curves

    shutil.copytree(tiny_ur5_run, tmp_path / "runs" / "run")
    draw = ["--out", str(tmp_path / "c.png")]
    assert run_main(curves.main, [str(tmp_path / "runs"), *draw])[0] == 0
    folder = RunFolder(tmp_path / "runs" / "run")
    spec = folder.read_spec()
    spec["task"][field] = value
    folder.spec_path.write_text(json.dumps(spec))
    code, err = run_main(curves.main, [str(tmp_path / "runs"), *draw])
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"{field}={value}" in err or repr(value) in err, err


def test_make_of_the_stack_twin_refuses_in_one_line_and_make_vec_builds_it():
    """gymnasium.make('UR5StackReach-v0') failed with Gymnasium's own 'entry_point is not
    specified', naming no way out; make_vec, the reference, builds the stack."""
    import gymnasium

    import envs  # noqa: F401  (registers the ids)

    with pytest.raises(ValueError, match=r"envs\.stackreach\.StackReach directly"):
        gymnasium.make("UR5StackReach-v0")
    stack = gymnasium.make_vec("UR5StackReach-v0", num_envs=2,
                               vectorization_mode="vector_entry_point",
                               tasks=[dict(region="farbox", n_joints=3)] * 2)
    assert type(stack).__name__ == "StackReach"


def test_the_stack_twins_reset_refuses_in_one_line_naming_reset_where():
    """make_vec('UR5StackReach-v0').reset(seed=0), a Gymnasium user's first call, ended in
    "AttributeError: 'StackReach' object has no attribute 'reset'"; it is now refused naming
    the stack's own start, reset_where, which (the reference) starts every copy at its goal."""
    import gymnasium
    import torch

    import envs  # noqa: F401  (registers the ids)

    stack = gymnasium.make_vec("UR5StackReach-v0", num_envs=2,
                               vectorization_mode="vector_entry_point",
                               tasks=[dict(region="farbox", n_joints=3)] * 2)
    with pytest.raises(ValueError, match=r"no Gymnasium reset\(\); start episodes with reset_wh"):
        stack.reset(seed=0)
    goal = torch.tensor([[0.4, 0.1, 0.5], [0.3, -0.2, 0.6]], dtype=torch.float64)
    stack.reset_where(torch.ones(2, dtype=torch.bool), goal)
    assert torch.equal(stack.goal, goal) and bool((stack.elapsed == 0).all())


def test_a_deep_copied_vector_reach_env_steps_as_the_original():
    """A deep copy or a pickle of UR5Reach-v0's vector env (numba dynamics) copied the
    observation's three joint-block views as arrays of their own: the copy's arm moved but its
    observation stayed at the reset pose, forever, without a word. The original env, stepped
    alike, is the reference."""
    import copy
    import pickle

    import gymnasium
    import numpy as np

    import envs  # noqa: F401  (registers the ids)

    kw = dict(region="farbox", n_joints=3)
    env = gymnasium.make_vec("UR5Reach-v0", num_envs=2, vectorization_mode="vector_entry_point",
                             dynamics="numba", **kw)
    start = env.reset(seed=0)[0]["observation"]
    copies = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    action = np.full(env.action_space.shape, 0.3)
    for _ in range(2):
        want = env.step(action)[0]["observation"]
        for other in copies:
            assert np.array_equal(other.step(action)[0]["observation"], want)
    assert not np.array_equal(want, start)


def test_optimality_reads_the_curves_runs_before_computing(tiny_ur5_run, tmp_path):
    """optimality --curves over a truncated eval.csv ended in a traceback after the whole
    study; it is now refused first, in one line naming the file, and nothing is written. The
    intact run, the reference, is drawn."""
    from analysis import optimality

    shutil.copytree(tiny_ur5_run, tmp_path / "runs" / "run")
    csv_in = Path(__file__).parents[1] / "results" / "optimality" / "optimality.csv"
    argv = ["--from-csv", str(csv_in), "--curves", str(tmp_path / "runs"), "--out"]
    assert run_main(optimality.main, [*argv, str(tmp_path / "ok")])[0] == 0
    assert (tmp_path / "ok" / "optimality_curves.png").exists()
    eval_csv = tmp_path / "runs" / "run" / "eval.csv"
    eval_csv.write_bytes(eval_csv.read_bytes()[:60])
    code, err = run_main(optimality.main, [*argv, str(tmp_path / "bad")])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "eval.csv" in err, err
    assert not (tmp_path / "bad").exists()


def test_load_names_a_checkpoint_of_another_joint_count(tiny_ur5_run, tmp_path):
    """A run folder whose spec.json says 4 joints holding a 3-joint checkpoint: replay ended in
    torch's size mismatch, naming no file. The unedited run, the reference, loads."""
    import math

    import ddpg_her
    from analysis import replay

    run = tmp_path / "run"
    shutil.copytree(tiny_ur5_run, run)
    assert ddpg_her.load(run).episode == 2
    folder = RunFolder(run)
    spec = folder.read_spec()
    spec["task"]["n_joints"] = spec["env_kwargs"]["n_joints"] = 4
    spec["dims"].update(obs_dim=12, act_dim=4, action_low=[-math.pi] * 4,
                        action_high=[math.pi] * 4)
    folder.spec_path.write_text(json.dumps(spec))
    with pytest.raises(ValueError, match=r"episode-000002\.pt does not fit spec\.json"):
        ddpg_her.load(run)
    code, err = run_main(replay.main, [str(run), "--out", str(tmp_path / "r.mp4")])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "episode-000002.pt" in err


def test_sweep_program_on_a_full_disk_ends_in_one_line(tmp_path, monkeypatch):
    """sweep --program on a full disk ended in a traceback (its plan and log are written by the
    sweep process itself); now one line, status 1, saying how to resume."""
    import errno

    from analysis import sweep
    from ddpg_her import units

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(units, "write_plan", full)
    code, err = run_main(sweep.main, ["--setting", "farbox:3", "--seeds", "1", "--episodes", "2",
                                      "--out", str(tmp_path / "sw"), "--program", "--",
                                      *TINY[2:]])
    assert code == 1, err
    assert "Traceback" not in err
    assert any(line.startswith("error: [Errno 28] No space left") and "again" in line
               for line in err.splitlines()), err


@pytest.mark.parametrize(("seeds", "dirs", "kwargs", "config", "match"), [
    ((0, 0), ("a", "b"), {}, {}, r"seeds=\(0, 0\) \(expected one or more distinct seeds"),
    ((-1,), ("a",), {}, {}, r"seeds=\(-1,\) \(expected one or more distinct seeds, integers >= 0"),
    ((0, 1), ("a", "a"), {}, {}, r"run_dirs=\('a', 'a'\) \(expected distinct run folders"),
    ((0,), ("a",), {"n_joints": 9}, {}, r"invalid task: n_joints=9 \(expected an integer in 2..6"),
    ((0,), ("a",), {"region": "nowhere"}, {}, "cannot read region 'nowhere'"),
    ((0,), ("a",), {}, {"her_k": 8}, "--her-k has no effect with --her-strategy final"),
])
def test_a_unit_of_training_is_one_record_whoever_builds_it(seeds, dirs, kwargs, config, match):
    """The reference is the command line: what ``train.request`` refuses, a Setting built in
    Python refuses with the same words (it took repeated seeds, one folder for two seeds, a
    task no env could make, and contradicting flags, which only the command checked)."""
    from ddpg_her.units import Setting

    env_kwargs = {"region": "farbox", "n_joints": 3, **kwargs}
    with pytest.raises(ValueError, match=match):
        Setting("UR5Reach-v0", env_kwargs, AgentConfig(**config), seeds, dirs)
    if seeds == (0, 0):
        code, err = run_main(train.main, ["--region", "farbox", "--seeds", "0", "0", "--out",
                                          "/nonexistent/s{seed}"])
        assert code == 2 and "seeds=(0, 0) (expected one or more distinct" in error_line(err)
