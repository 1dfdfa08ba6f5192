"""Issue 16 on the envs, the reward and ur5kin: misuse and bad input get a clear error (never a
silently wrong value), and ``info`` reports the arm's clearance above the plane."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import envs
import ur5kin
from envs import UR5ReachEnv

TASK = {"region": "farbox", "n_joints": 3}


# --- step before reset ------------------------------------------------------------------------
def test_stepping_before_reset_is_an_error_not_a_reward_for_reaching_the_origin():
    env = UR5ReachEnv(**TASK)  # no OrderEnforcing wrapper: the env itself must refuse
    with pytest.raises(gymnasium.error.ResetNeeded, match="before reset"):
        env.step(np.zeros(3))
    env.reset(seed=0)
    env.step(np.zeros(3))  # and after a reset it steps


def test_stepping_a_vector_env_before_reset_is_an_error_for_every_copy_never_reset():
    vec = envs.BatchedReach(2, **TASK)
    with pytest.raises(gymnasium.error.ResetNeeded, match=r"copies \[0, 1\] of 2"):
        vec.step(np.zeros((2, 3)))
    vec.reset(seed=0, options={"reset_mask": np.array([True, False])})
    with pytest.raises(gymnasium.error.ResetNeeded, match=r"copy \[1\] of 2"):
        vec.step(np.zeros((2, 3)))
    vec.reset(seed=0)
    vec.step(np.zeros((2, 3)))


# --- actions that are not numbers -------------------------------------------------------------
@pytest.mark.parametrize("action", ["abc", None, [1j, 0, 0], {"a": 1}])
def test_a_non_numeric_action_is_a_value_error_naming_it(action):
    env = UR5ReachEnv(**TASK)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be 3 finite numbers.*got"):
        env.step(action)
    vec = envs.BatchedReach(2, **TASK)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions must be a finite \(2, 3\) array"):
        vec.step([action, action])


# --- compute_reward / compute_success ---------------------------------------------------------
def reward_env() -> UR5ReachEnv:
    return UR5ReachEnv(**TASK)


@pytest.mark.parametrize("achieved, desired, action, message", [
    ([np.nan, 0, 0], np.zeros(3), np.zeros(3), r"achieved_goal must be finite.*achieved_goal\[0\]"),
    (np.zeros(3), [0, np.inf, 0], np.zeros(3), r"desired_goal must be finite"),
    (np.zeros(3), np.zeros(2), np.zeros(3), r"desired_goal must have shape \(\.\.\., 3\)"),
    (np.zeros((4, 3)), np.zeros((5, 3)), np.zeros((4, 3)),
     r"achieved_goal \(4, 3\) and desired_goal \(5, 3\) must have batch shapes that broadcast"),
    (np.zeros((4, 3)), np.zeros((4, 3)), np.zeros((5, 3)),
     r"info\['action'\] \(5, 3\) does not fit the goals' batch shape \(4,\)"),
    (np.zeros(3), np.zeros(3), np.zeros(2), r"info\['action'\] must have shape \(\.\.\., 3\)"),
    (np.zeros(3), np.zeros(3), [np.nan, 0, 0], r"info\['action'\] must be finite"),
    (np.zeros(3) + 1j, np.zeros(3), np.zeros(3),
     r"achieved_goal must be real numbers .*got complex"),
    ("abc", np.zeros(3), np.zeros(3), r"achieved_goal must be real numbers"),
])
def test_compute_reward_refuses_bad_goals_and_actions(achieved, desired, action, message):
    env = reward_env()
    with pytest.raises(ValueError, match=message):
        env.compute_reward(achieved, desired, {"action": action})
    if "action" not in message:
        with pytest.raises(ValueError, match=message):
            env.compute_terminated(achieved, desired, {})


def test_compute_reward_still_broadcasts_goals():
    env = reward_env()
    goals = np.random.default_rng(0).normal(size=(4, 3))
    reward = env.compute_reward(goals, goals[0], {"action": np.zeros((4, 3))})
    distance = np.linalg.norm(goals - goals[0], axis=-1)
    np.testing.assert_allclose(reward, -distance + 100.0 * (distance <= 0.1))


# --- ur5kin -----------------------------------------------------------------------------------
@pytest.mark.parametrize("function", [ur5kin.fk, ur5kin.fk_pose, ur5kin.jacobian])
@pytest.mark.parametrize("q", [np.array([1 + 1j, 0, 0, 0, 0, 0]), np.zeros((2, 6)) + 0j,
                               "abcdef"])
def test_ur5kin_refuses_complex_and_non_numeric_angles(function, q):
    with pytest.raises(ValueError, match=r"q must be real numbers \(joint "
                                         r"angles in rad\)"):
        function(q)


def test_ik_position_speaks_of_a_position_in_m_for_its_target():
    with pytest.raises(ValueError, match=r"target must have shape \(\.\.\., 3\) \(tool0 "
                                         r"positions x, y, z in m") as err:
        ur5kin.ik_position([0.3, 0.2], [0.0, 0.0, 0.0])
    assert "joint angles" not in str(err.value)
    with pytest.raises(ValueError, match=r"wrist must have shape \(\.\.\., 3\) \(angles of "
                                         r"joints 4-6 in rad\)"):
        ur5kin.ik_position([0.3, 0.2, 0.4], [0.0, 0.0])
    with pytest.raises(ValueError, match=r"target \(2, 3\) and wrist \(3, 3\) must have batch"):
        ur5kin.ik_position(np.zeros((2, 3)), np.zeros((3, 3)))


# --- info["clearance"] ------------------------------------------------------------------------
def lowest_link(q: np.ndarray, base_height: float) -> np.ndarray:
    """The second path: link heights computed directly, minimum over the moving links."""
    return ur5kin.link_heights(q, base_height)[..., 1:].min(axis=-1)


def test_an_env_id_gymnasium_does_not_know_is_a_usage_error_naming_it(capsys, tmp_path):
    """Issue 37, kind 4 (found by benchmarks/reliability_probe.py): ``analysis.sb3 --env-id
    NoSuch-v0`` ended in Gymnasium's NameNotFound traceback; it now checks the id through
    ddpg_her.train.register_envs, as train and train_many do, before any work."""
    from analysis import sb3

    with pytest.raises(SystemExit) as stop:
        sb3.main(["--region", "farbox", "--env-id", "NoSuch-v0", "--episodes", "2", "--out",
                  str(tmp_path / "r")])
    assert stop.value.code == 2
    assert "--env-id NoSuch-v0: not a registered Gymnasium id" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_info_clearance_is_the_lowest_moving_link_height_at_the_end_of_the_step():
    env = UR5ReachEnv(**TASK)
    rng = np.random.default_rng(1)
    _, info = env.reset(seed=1)
    base = env.task.base_height
    assert info["clearance"] == pytest.approx(lowest_link(env.joint_angles, base), abs=1e-12)
    seen = []
    for _ in range(60):
        _, _, terminated, truncated, info = env.step(rng.uniform(-np.pi, np.pi, 3))
        expected = float(lowest_link(env.joint_angles, base))
        assert info["clearance"] == pytest.approx(expected, abs=1e-12)
        assert info["clearance"] >= -1e-9  # the plane holds
        seen.append(info["clearance"])
        if terminated or truncated:
            env.reset()
    assert np.ptp(seen) > 0.05  # the arm moved, the value followed

    vec = envs.BatchedReach(3, **TASK)
    vec.reset(seed=2)
    for _ in range(20):
        _, _, _, _, info = vec.step(rng.uniform(-np.pi, np.pi, (3, 3)))
        q = vec._core.dynamics.q
        np.testing.assert_allclose(info["clearance"], lowest_link(q, base), atol=1e-12)
        assert info["_clearance"].all()


@pytest.mark.parametrize(("args", "message"), [
    (["--goals", "0"], "argument --goals: 0 (expected an integer >= 1)"),
    (["--steps", "-1"], "argument --steps: -1 (expected an integer >= 1)"),
    (["--rounds", "0"], "argument --rounds: 0 (expected an integer >= 1)"),
    (["--friction", "nan"], "argument --friction: nan (expected a finite number"),
    (["--joints", "7"], "n_joints=7 (expected an integer in 2..6)"),
    (["--region", "nowhere"], "cannot read region 'nowhere'"),
    # issue 37, kind 7: numpy's ValueError and the sampler's error were tracebacks
    (["--seed", "-1"], "argument --seed: -1 (expected an integer >= 0 (numpy's seeds are))"),
    (["--region", "box:5,6,5,6,5,6", "--goals", "2", "--steps", "2", "--rounds", "1"],
     "--region box:5,6,5,6,5,6: region 'box:5,6,5,6,5,6' has no goals reachable with 3 joints"),
])
def test_the_contact_study_refuses_what_it_cannot_measure(args, message, capsys):
    from analysis import contact

    with pytest.raises(SystemExit) as stop:
        contact.main(args)
    assert stop.value.code == 2
    assert message in capsys.readouterr().err


def test_a_success_map_of_a_run_of_another_env_is_refused_naming_it(capsys, tmp_path):
    """Issue 37, kind 7 (found by benchmarks/reliability_probe.py): success_map of a run of
    the toy goal env ended in TaskSpec's "unknown task field(s)" traceback (and one whose
    spec.json lost its env_id was mapped in the UR5 env without a word)."""
    from cli_tools import run_module

    from analysis import success_map

    run = tmp_path / "toy"
    run_module("ddpg_her.train", "--env-id", "toy_goal_env:ToyReach-v0", "--region", "box",
               "--joints", "2", "--episodes", "2", "--eval-every", "2", "--eval-episodes", "1",
               "--hidden-sizes", "8", "8", "--warmup-episodes", "1", "--batch-size", "8",
               "--buffer-size", "100", "--no-progress", "--no-tensorboard", "--out", str(run))
    with pytest.raises(SystemExit) as stop:
        success_map.main([str(run), "--goals", "4", "--z", "0.1", "0.3", "--out",
                          str(tmp_path / "m.png"), "--no-progress"])
    assert stop.value.code == 2
    assert f"{run} is a run of env 'toy_goal_env:ToyReach-v0'; only runs of UR5Reach-v0 " \
           "can be mapped" in capsys.readouterr().err
    assert not (tmp_path / "m.png").exists()


@pytest.mark.parametrize(("args", "message"), [
    (["--cell", "1e-6"], "--cell 1e-06 m would need about"),
    (["--goals", "100000000000"], "--goals 100000000000 and --cell 0.1 m would need about"),
])
def test_a_success_map_that_cannot_fit_is_refused_before_any_rollout(args, message, capsys,
                                                                       tmp_path):
    from analysis import success_map

    with pytest.raises(SystemExit) as stop:
        success_map.main([str(tmp_path / "no-run-needed"), *args,
                          "--out", str(tmp_path / "map.png")])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "GiB of memory available" in err


@pytest.mark.parametrize("section", ["task", "env_kwargs"])
@pytest.mark.parametrize(("region", "message"), [
    ("nowhere", "cannot read region 'nowhere'"),
    ("box:1,0,0,1", "region 'box:1,0,0,1': expected 6 numbers (m); got 4"),
])
@pytest.mark.parametrize("module", ["analysis.success_map", "analysis.replay"])
def test_a_run_whose_spec_names_an_unreadable_region_is_one_line_naming_it(
        tiny_ur5_run, tmp_path, capsys, module, region, message, section):
    """Issue 37, kind 7: success_map and replay ended a run whose spec.json names a region
    that does not parse in the region parser's traceback (replay after its set-up, success_map
    after loading every checkpoint); every reader goes through ddpg_her.load, which now makes
    the run's env once and names spec.json."""
    import importlib
    import json
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_ur5_run, run)
    spec = json.loads((run / "spec.json").read_text())
    spec[section]["region"] = region
    (run / "spec.json").write_text(json.dumps(spec))
    main = importlib.import_module(module).main
    with pytest.raises(SystemExit) as stop:
        out = "out.html" if module == "analysis.replay" else "out.png"
        main([str(run), "--out", str(tmp_path / out), "--no-progress"]
             + (["--episodes", "1"] if module == "analysis.replay" else ["--goals", "20"]))
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert message in last and str(run / "spec.json") in last, err
    assert not list(tmp_path.glob("out*"))


def test_load_names_the_spec_whose_env_cannot_be_made(tiny_ur5_run, tmp_path):
    import json
    import shutil

    import ddpg_her
    from ddpg_her.runfolder import RunFolderError

    assert ddpg_her.load(tiny_ur5_run).task.region == "farbox"
    run = tmp_path / "run"
    shutil.copytree(tiny_ur5_run, run)
    spec = json.loads((run / "spec.json").read_text())
    spec["task"]["region"] = "nowhere"
    (run / "spec.json").write_text(json.dumps(spec))
    with pytest.raises(RunFolderError, match=r"spec\.json: the run's env cannot be made.*"
                                             r"cannot read region 'nowhere'"):
        ddpg_her.load(run)


@pytest.mark.parametrize(("section", "key", "value"), [
    ("env_kwargs", "region", "zheight"), ("task", "region", "zheight"),
    ("env_kwargs", "n_joints", 4)])
def test_a_spec_whose_task_and_env_kwargs_disagree_is_refused_naming_the_field(
        tiny_ur5_run, tmp_path, section, key, value):
    """Issue 37, kind 6 (an inconsistent spec is not noticed): a far-box run's spec edited to
    name another region (or joint count) in one of its two records was read as the env_kwargs'
    task, without a word; every reader goes through ddpg_her.load's run_task, which compares
    the made env's task with the recorded one."""
    import json
    import shutil

    import ddpg_her
    from ddpg_her.runfolder import RunFolderError

    run = tmp_path / "run"
    shutil.copytree(tiny_ur5_run, run)
    ddpg_her.load(run)  # the untouched spec is consistent
    spec = json.loads((run / "spec.json").read_text())
    spec[section][key] = value
    (run / "spec.json").write_text(json.dumps(spec))
    with pytest.raises(RunFolderError, match=rf"spec\.json: its task and its env_kwargs "
                                             rf"disagree on {key} "):
        ddpg_her.load(run)


def test_load_of_a_spec_without_env_id_names_it(tiny_ur5_run, tmp_path):
    """Issue 37, kind 6: load makes the run's env once; a spec without ``env_id`` was a
    ``KeyError: 'env_id'`` inside the message, now a sentence naming the key and the file."""
    import json
    import shutil

    import ddpg_her
    from ddpg_her.runfolder import RunFolderError

    run = tmp_path / "run"
    shutil.copytree(tiny_ur5_run, run)
    spec = json.loads((run / "spec.json").read_text())
    del spec["env_id"]
    (run / "spec.json").write_text(json.dumps(spec))
    with pytest.raises(RunFolderError, match=r"spec\.json names no env_id \(the Gymnasium id"):
        ddpg_her.load(run)


def test_a_success_map_refuses_a_negative_seed_before_loading_any_run(capsys, tmp_path):
    """Issue 37, kind 7 (found by benchmarks/reliability_probe.py): ``--seed -1`` reached
    numpy's "expected non-negative int" after the policies were loaded, and was reported as
    "no goals in the slice"."""
    from analysis import success_map

    with pytest.raises(SystemExit) as stop:
        success_map.main([str(tmp_path / "no-run-needed"), "--seed", "-1", "--out",
                          str(tmp_path / "map.png")])
    assert stop.value.code == 2
    assert "argument --seed: -1 (expected an integer >= 0 (numpy's seeds are))" in \
        capsys.readouterr().err


def test_compute_reward_refuses_a_list_of_infos_that_does_not_match_the_batch():
    """Issue 37, kind 8: one info for four transitions was broadcast over them silently."""
    env = reward_env()
    goals = np.random.default_rng(0).normal(size=(4, 3))
    infos = [{"action": np.full(3, 0.5)}]
    with pytest.raises(ValueError, match=r"\(1,\) infos for goals of batch shape \(4,\)"):
        env.compute_reward(goals, goals[0], infos)
    one_each = env.compute_reward(goals, goals[0], infos * 4)  # one per transition: fine
    np.testing.assert_allclose(one_each, env.compute_reward(goals, goals[0],
                                                            {"action": np.full((4, 3), 0.5)}))


def test_a_reward_that_is_not_finite_is_an_error_naming_where():
    env = reward_env()
    with pytest.raises(ValueError, match=r"the reward is not finite at \[\]"):
        env.compute_reward(np.zeros(3), np.zeros(3), {"action": np.full(3, 1e200)})
