"""analysis.sb3: SB3's algorithms + HER under the paper's protocol, on the toy goal env."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import toy_goal_env
from cli_tools import run_module

from analysis import sb3
from ddpg_her.runfolder import EVAL_COLUMNS, read_run

TINY = {"common": {"gamma": 0.98, "batch_size": 16, "buffer_size": 5000, "tau": 0.05,
                   "learning_rate": 1e-3, "learning_starts": 40, "train_freq": [1, "episode"],
                   "gradient_steps": -1, "policy_kwargs": {"net_arch": [16, 16]},
                   "replay_buffer_kwargs": {"goal_selection_strategy": "final",
                                            "n_sampled_goal": 1, "copy_info_dict": True}},
        "ddpg": {"action_noise_std": 0.1}, "td3": {"action_noise_std": 0.1}, "sac": {}}


def test_the_shipped_hyperparameters_are_table_one_where_sb3_has_the_knob():
    for algo in sb3.ALGOS:
        h = sb3.load_hyperparams(sb3.DEFAULT_HYPERPARAMS, algo)
        assert (h["gamma"], h["batch_size"], h["buffer_size"], h["tau"]) == (
            0.98, 64, 1_000_000, 0.001)
        assert h["policy_kwargs"]["net_arch"] == [400, 300]
        assert h["replay_buffer_kwargs"]["copy_info_dict"] is True  # the dense reward's action
    assert sb3.load_hyperparams(sb3.DEFAULT_HYPERPARAMS, "td3")["policy_delay"] == 2


@pytest.mark.parametrize("algo, vec_normalize", [
    ("ddpg", None), ("sac", None), ("ddpg", {"norm_obs": True, "norm_reward": False})])
def test_a_tiny_run_writes_the_eval_csv_every_analysis_reads(tmp_path: Path, algo: str,
                                                             vec_normalize: dict | None):
    tiny = json.loads(json.dumps(TINY))
    if vec_normalize is not None:
        tiny["common"]["vec_normalize"] = vec_normalize
    params = tmp_path / "h.json"
    params.write_text(json.dumps(tiny))
    out = tmp_path / algo
    first = run_module("analysis.sb3", "--algo", algo, "--env-id", "toy_goal_env:ToyReach-v0",
                       "--region", "box", "--joints", "2", "--episodes", "6", "--eval-every",
                       "3", "--eval-episodes", "4", "--hyperparams", str(params), "--out",
                       str(out))
    assert "episode 3/6: " in first.stderr and "episode 6/6: " in first.stderr  # progress
    run = read_run(out)
    assert list(run.episode) == [3, 6] and list(run.tests) == [4, 4]
    assert run.setting == ("box", 2) and run.spec["agent"]["algo"] == f"sb3-{algo}"
    assert run.spec["agent"]["sb3"].get("vec_normalize") == vec_normalize
    header = (out / "eval.csv").read_text().splitlines()[0]
    assert tuple(header.split(",")) == EVAL_COLUMNS
    steps = [int(line.split(",")[5]) for line in (out / "eval.csv").read_text().splitlines()[1:]]
    assert steps[1] > 6  # episodes of more than one step (see the seeding test)
    again = run_module("analysis.sb3", "--algo", algo, "--env-id", "toy_goal_env:ToyReach-v0",
                       "--region", "box", "--joints", "2", "--hyperparams", str(params),
                       "--out", str(out), check=False)
    assert again.returncode != 0 and f"{out} exists" in again.stderr


def test_warm_up_actions_do_not_replay_the_envs_goal_draws():
    """SB3 seeds the action space and the env's reset alike: on the toy env each uniform warm-up
    action was exactly twice the goal (every episode a success at step 1) until sb3 reseeded."""
    env = gymnasium.make(toy_goal_env.ENV_ID, n_joints=2)
    model = sb3.make_model("sac", env, sb3.load_hyperparams_dict(TINY, "sac"), seed=0)
    goal = env.reset(seed=0)[0]["desired_goal"]
    assert not np.allclose(model.action_space.sample(), 2 * goal)


def test_bad_hyperparameter_files_are_named():
    with pytest.raises(ValueError, match="no section 'sac'"):
        sb3.load_hyperparams_dict({"ddpg": {}}, "sac")
    proc = run_module("analysis.sb3", "--region", "farbox", "--hyperparams", "/nonexistent.json",
                      check=False)
    assert proc.returncode != 0 and "/nonexistent.json" in proc.stderr


def test_the_vecnormalize_file_is_the_default_plus_sb3s_normaliser():
    vn = sb3.ROOT / "examples" / "sb3_her_vecnormalize.json"
    for algo in sb3.ALGOS:
        plain = sb3.load_hyperparams(sb3.DEFAULT_HYPERPARAMS, algo)
        normed = sb3.load_hyperparams(vn, algo)
        assert normed.pop("vec_normalize") == {"norm_obs": True, "norm_reward": False,
                                               "clip_obs": 5.0, "epsilon": 1e-4}
        assert normed == plain


def test_under_vecnormalize_the_policy_sees_the_training_statistics():
    """The test sessions feed the policy what it trained on: (x - mean) / sqrt(var + eps),
    clipped, per key, by the VecNormalize statistics (a hand computation as the reference)."""
    params = {**TINY["common"], **TINY["ddpg"],
              "vec_normalize": {"norm_obs": True, "norm_reward": False, "clip_obs": 2.0,
                                "epsilon": 1e-4}}
    env = gymnasium.make(toy_goal_env.ENV_ID, n_joints=2)
    model = sb3.make_model("ddpg", env, params, seed=0)
    norm = model.get_vec_normalize_env()
    rng = np.random.default_rng(0)
    for rms in norm.obs_rms.values():
        rms.mean = rng.normal(size=rms.mean.shape)
        rms.var = rng.uniform(0.01, 4.0, size=rms.var.shape)
    batch = {k: rng.normal(scale=3.0, size=(5, *space.shape))
             for k, space in env.observation_space.spaces.items()}
    seen = sb3.policy_input(model, batch)
    for k, x in batch.items():
        rms = norm.obs_rms[k]
        want = np.clip((x - rms.mean) / np.sqrt(rms.var + 1e-4), -2.0, 2.0)
        np.testing.assert_allclose(seen[k], want, rtol=1e-6, atol=1e-6)
    plain = sb3.make_model("ddpg", env, sb3.load_hyperparams_dict(TINY, "ddpg"), seed=0)
    assert sb3.policy_input(plain, batch) is batch
    with pytest.raises(ValueError,
                       match=r"vec_normalize = true \(true/false\): expected an object"):
        sb3.make_model("ddpg", env, {**params, "vec_normalize": True}, seed=0)


def test_making_a_model_leaves_the_hyperparameters_as_they_were():
    """SB3's SAC writes use_sde into the policy_kwargs it is given; the run's spec.json records
    the hyperparameters, so they must be what the file said."""
    params = sb3.load_hyperparams_dict(json.loads(json.dumps(TINY)), "sac")
    before = json.dumps(params, sort_keys=True)
    sb3.make_model("sac", gymnasium.make(toy_goal_env.ENV_ID, n_joints=2), params, seed=0)
    assert json.dumps(params, sort_keys=True) == before


def test_a_run_that_fails_before_its_first_test_leaves_no_folder_to_block_the_rerun(
        tmp_path: Path, monkeypatch):
    """Issue 37, kind 3: a failed run left a spec.json, and the corrected rerun was refused
    ("exists; SB3 runs do not resume")."""
    made = sb3.make_model

    def failing(*args, **kwargs):
        model = made(*args, **kwargs)

        def learn(**_):
            raise RuntimeError("diverged")

        model.learn = learn
        return model

    monkeypatch.setattr(sb3, "make_model", failing)
    out = tmp_path / "run"
    toy = {"region": "box", "n_joints": 2}
    with pytest.raises(RuntimeError, match="diverged"):
        sb3.train("ddpg", "toy_goal_env:ToyReach-v0", toy, 0, 2, 1, 1, TINY_DDPG, out)
    assert not out.exists()
    monkeypatch.setattr(sb3, "make_model", made)
    rows = sb3.train("ddpg", "toy_goal_env:ToyReach-v0", toy, 0, 2, 1, 1, TINY_DDPG, out)
    assert [r["episode"] for r in rows] == [1, 2]


TINY_DDPG = sb3.load_hyperparams_dict(TINY, "ddpg")


BAD_HYPERPARAMS = [
    ("ddpg", {"gama": 0.9}, ["'gama'", "gamma", "batch_size", "tau"]),
    ("sac", {"policy_delay": 2}, ["'policy_delay'", "ent_coef"]),
    ("ddpg", {"gamma": "high"}, ["gamma", '"high"', "a string", "expected a number"]),
    ("ddpg", {"batch_size": 64.0}, ["batch_size", "64.0", "expected an integer"]),
    ("td3", {"batch_size": True}, ["batch_size", "true", "expected an integer"]),
    ("ddpg", {"train_freq": "1"}, ["train_freq", '"1"', "an integer or a list"]),
    ("td3", {"train_freq": [1, "epoch"]}, ["train_freq", "'epoch'", "'step' or 'episode'"]),
    ("sac", {"ent_coef": [1]}, ["ent_coef", "a list", "a string or a number"]),
    ("ddpg", {"action_noise_std": "0.1"}, ["action_noise_std", '"0.1"', "a number"]),
    ("ddpg", {"action_noise_std": -0.1}, ["action_noise_std", "-0.1", ">= 0"]),
    ("ddpg", {"seed": 3}, ["seed", "--seed"]),
    ("ddpg", {"device": "cuda"}, ["device", "analysis.sb3 itself"]),
    ("ddpg", {"action_noise": 0.1}, ["action_noise", "action_noise_std"]),
    ("ddpg", {"policy_kwargs": {"net_arch": [16, "16"]}},
     ["policy_kwargs.net_arch", '[16, "16"]', "a list of integers"]),
    ("ddpg", {"policy_kwargs": {"activation_fn": "tanh"}},
     ["policy_kwargs.activation_fn", "JSON file cannot give"]),
    ("ddpg", {"policy_kwargs": {"hidden": [8]}}, ["'policy_kwargs.hidden'", "net_arch"]),
    ("ddpg", {"replay_buffer_kwargs": {"goal_selection_strategy": "past"}},
     ["goal_selection_strategy", "'past'", "one of ['future', 'final', 'episode']"]),
    ("ddpg", {"replay_buffer_kwargs": {"n_sampled_goal": "4"}},
     ["replay_buffer_kwargs.n_sampled_goal", '"4"', "an integer"]),
    ("ddpg", {"replay_buffer_kwargs": {"env": None}}, ["replay_buffer_kwargs.env", "SB3 itself"]),
    ("ddpg", {"vec_normalize": {"clipobs": 5}}, ["'vec_normalize.clipobs'",
                                                 "vec_normalize.clip_obs"]),
    ("ddpg", {"vec_normalize": {"clip_obs": "5"}}, ["vec_normalize.clip_obs", "a number"]),
    # of the right type but out of range (SB3 took each, and trained on nonsense or failed late)
    ("ddpg", {"gamma": 2}, ["gamma=2 (expected a number in [0, 1])"]),
    ("td3", {"tau": 0}, ["tau=0 (expected a number in (0, 1])"]),
    ("sac", {"learning_rate": -0.001}, ["learning_rate=-0.001 (expected a finite number > 0)"]),
    ("ddpg", {"batch_size": 0}, ["batch_size=0 (expected an integer >= 1)"]),
    ("ddpg", {"learning_starts": -5}, ["learning_starts=-5 (expected an integer >= 0)"]),
    ("ddpg", {"gradient_steps": 0}, ["gradient_steps=0", "or -1"]),
    ("td3", {"train_freq": [0, "step"]}, ["train_freq=[0, 'step']", "integer >= 1"]),
    ("td3", {"policy_delay": 0}, ["policy_delay=0"]),
    ("ddpg", {"replay_buffer_kwargs": {"n_sampled_goal": 0}},
     ["replay_buffer_kwargs.n_sampled_goal=0 (expected an integer >= 1)"]),
    ("ddpg", {"policy_kwargs": {"net_arch": [16, 0]}},
     ["policy_kwargs.net_arch=[16, 0]", "integers >= 1"]),
    ("ddpg", {"batch_size": 64, "buffer_size": 32, "learning_starts": 0},
     ["batch_size=64 (expected at most buffer_size)"]),
    ("ddpg", {"buffer_size": 100, "learning_starts": 100, "batch_size": 8},
     ["learning_starts=100 (expected below buffer_size"]),
]
"""(algorithm, keys merged into TINY's section, what the message must name)."""


@pytest.mark.parametrize("algo, extra, words", BAD_HYPERPARAMS,
                         ids=[f"{a}-{next(iter(e))}-{i}" for i, (a, e, _) in
                              enumerate(BAD_HYPERPARAMS)])
def test_hyperparameters_sb3_would_not_take_are_refused_in_our_words(algo, extra, words):
    """Issue 37, kind 4: an unknown key names the key and the allowed ones, a value of the wrong
    type names the value and the type expected, a key the command sets names what sets it;
    before SB3 sees them (SB3's own answers: a TypeError traceback for an unknown keyword, a
    failure deep inside the first update, or nothing at all)."""
    data = json.loads(json.dumps(TINY))
    data[algo] = {**data[algo], **extra}
    with pytest.raises(ValueError) as err:
        sb3.load_hyperparams_dict(data, algo)
    message = str(err.value)
    assert "\n" not in message
    for word in words:
        assert word in message, (word, message)


def test_the_library_calls_go_through_the_same_check(tmp_path: Path):
    """``train`` and ``make_model`` called from Python (no file) refuse what the file would,
    before any folder: SB3 took gamma 2 and trained on it."""
    bad = {**TINY_DDPG, "gamma": 2}
    out = tmp_path / "run"
    with pytest.raises(ValueError, match=r"ddpg: invalid hyperparameters: gamma=2 \(expected"):
        sb3.train("ddpg", "toy_goal_env:ToyReach-v0", {"region": "box", "n_joints": 2}, 0, 2,
                  1, 1, bad, out)
    assert not out.exists()
    with pytest.raises(ValueError, match="unknown hyperparameter 'gama'"):
        sb3.make_model("ddpg", gymnasium.make(toy_goal_env.ENV_ID, n_joints=2),
                       {**TINY_DDPG, "gama": 0.9}, seed=0)


def test_an_unknown_section_of_the_file_is_refused():
    with pytest.raises(ValueError, match=r"'ppo'.*common, ddpg, td3, sac"):
        sb3.load_hyperparams_dict({**TINY, "ppo": {}}, "ddpg")
    assert sb3.load_hyperparams_dict({**TINY, "_about": "a comment"}, "ddpg") == TINY_DDPG


@pytest.mark.parametrize("algo", sb3.ALGOS)
def test_what_the_check_lets_through_sb3_builds(algo):
    """The check is no stricter than SB3: keys and values of every kind it accepts (an integer
    for a float, null for an optional, lists for tuples, nested objects) build the model."""
    extra = {"ddpg": {"n_steps": 1, "tau": 1, "action_noise_std": None,
                      "policy_kwargs": {"net_arch": {"pi": [8], "qf": [8]}, "n_critics": 1}},
             "td3": {"stats_window_size": 10, "target_noise_clip": 0.5, "policy_delay": 3,
                     "vec_normalize": {"clip_obs": 5, "norm_reward": False},
                     "replay_buffer_kwargs": {"goal_selection_strategy": "future",
                                              "n_sampled_goal": 2,
                                              "handle_timeout_termination": True}},
             "sac": {"ent_coef": 0.1, "target_entropy": -2, "use_sde": False,
                     "train_freq": 1, "policy_kwargs": {"log_std_init": -2,
                                                        "net_arch": [8, 8]}}}[algo]
    data = json.loads(json.dumps(TINY))
    data[algo] = {**data[algo], **extra}
    params = sb3.load_hyperparams_dict(data, algo)
    env = gymnasium.make(toy_goal_env.ENV_ID, n_joints=2)
    model = sb3.make_model(algo, env, params, seed=0)
    assert model.gamma == TINY["common"]["gamma"]


def test_a_bad_hyperparameter_file_ends_the_command_in_one_line_before_any_folder(tmp_path):
    params = tmp_path / "bad.json"
    data = json.loads(json.dumps(TINY))
    data["common"]["gamma"] = "high"
    params.write_text(json.dumps(data))
    out = tmp_path / "run"
    proc = run_module("analysis.sb3", "--env-id", "toy_goal_env:ToyReach-v0", "--region", "box",
                      "--joints", "2", "--episodes", "1", "--hyperparams", str(params),
                      "--out", str(out), check=False)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "gamma" in last and '"high"' in last and str(params) in last
    assert not out.exists()


def test_the_sb3_example_trains_on_the_env_as_given(tmp_path: Path):
    """examples/sb3_her.py, as the README gives it, on a tiny budget: SB3 + HER on UR5Reach-v0
    with the dense reward (HER relabels through copy_info_dict); it trains and tests."""
    import subprocess
    import sys

    from cli_tools import ROOT, child_env

    out = subprocess.run([sys.executable, str(ROOT / "examples" / "sb3_her.py"), "--timesteps",
                          "200", "--test-episodes", "1"], capture_output=True, text=True,
                         env=child_env(), timeout=1200, check=False, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("of 1 test goals reached after 200 steps"), out.stdout


def test_sb3_her_without_the_infos_stops_on_the_dense_reward_saying_why():
    """What the README says SB3 needs: without copy_info_dict, HER's relabelled rewards lack
    the action of eq. 2's penalty, and the env's compute_reward stops it naming the fix."""
    import gymnasium
    from stable_baselines3 import DDPG, HerReplayBuffer

    import envs  # noqa: F401

    env = gymnasium.make("UR5Reach-v0", region="farbox", n_joints=3, max_episode_steps=20)
    model = DDPG("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer,
                 learning_starts=40, batch_size=16, seed=0, device="cpu",
                 policy_kwargs={"net_arch": [16, 16]})
    with pytest.raises(ValueError, match="copy_info_dict=True"):
        model.learn(total_timesteps=80)
