"""``python -m analysis.sb3``: Stable-Baselines3's DDPG, TD3 or SAC with its HerReplayBuffer on
UR5Reach-v0, unmodified, under the paper's protocol, into a run folder every analysis reads.

    python -m analysis.sb3 --algo ddpg --region farbox --joints 3 --seed 0 --episodes 1000
    python -m analysis.sb3 --algo td3 --region zheight --hyperparams my_copy.json

Every --eval-every training episodes, a test session of --eval-episodes
episodes of the deterministic policy, their goals those of ``ddpg_her.train``'s sessions for the
same seed; one row each in ``eval.csv`` (``ddpg_her.runfolder.EVAL_COLUMNS``) beside a
``spec.json``. The hyperparameters are one JSON file (default ``examples/sb3_her.json``: Table I
where SB3 has the knob, and where it has not, said there); a ``vec_normalize`` entry (an object
of ``VecNormalize``'s keyword arguments) trains under SB3's input normaliser, as
``examples/sb3_her_vecnormalize.json``. A run is not resumable: an existing folder is refused.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import datetime
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_HYPERPARAMS = ROOT / "examples" / "sb3_her.json"
"""The hyperparameter file a user copies."""

ACTION_STREAM = 1
"""Key of the warm-up actions' seed stream, ``SeedSequence([seed, ACTION_STREAM])``."""

ALGOS = ("ddpg", "td3", "sac")
"""The SB3 algorithms this recipe trains."""


def load_hyperparams(path: Path, algo: str) -> dict[str, Any]:
    """The keyword arguments of SB3's ``algo`` from the file: its ``common`` section updated by
    the algorithm's own (``action_noise_std`` stays a number; `make_model` turns it into noise).

    Raises
    ------
    ValueError
        When the file is not JSON or lacks the algorithm's section; the message names it.
    """
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"cannot read the hyperparameter file {path}: {err}") from err
    try:
        return load_hyperparams_dict(data, algo)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from err


def load_hyperparams_dict(data: dict[str, Any], algo: str) -> dict[str, Any]:
    """`load_hyperparams` of a file's content already read."""
    if algo not in data:
        raise ValueError(f"no section {algo!r} (sections: {sorted(data)})")
    return {**data.get("common", {}), **data[algo]}


def make_model(algo: str, env: Any, hyperparams: dict[str, Any], seed: int) -> Any:
    """SB3's ``algo`` on ``env`` with its HerReplayBuffer and the file's hyperparameters."""
    import stable_baselines3 as sb3
    from stable_baselines3 import HerReplayBuffer
    from stable_baselines3.common.noise import NormalActionNoise

    kwargs = copy.deepcopy(hyperparams)  # SB3 writes into policy_kwargs (SAC: use_sde)
    norm = kwargs.pop("vec_normalize", None)
    if norm is not None:
        # SB3's own input normaliser (ours keeps one per agent, clipped at +-5 std): the buffer
        # stores raw observations and normalises each sampled batch, relabelled goals included
        from stable_baselines3.common.monitor import Monitor
        from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

        if not isinstance(norm, dict):
            raise ValueError(f"vec_normalize must be an object of VecNormalize's keyword "
                             f"arguments, got {norm!r}")
        raw = env
        env = VecNormalize(DummyVecEnv([lambda: Monitor(raw)]), **norm)
    std = kwargs.pop("action_noise_std", None)
    if std:
        dim = env.action_space.shape[0]
        kwargs["action_noise"] = NormalActionNoise(np.zeros(dim), std * np.ones(dim))
    if "train_freq" in kwargs and isinstance(kwargs["train_freq"], list):
        kwargs["train_freq"] = tuple(kwargs["train_freq"])
    cls = {"ddpg": sb3.DDPG, "td3": sb3.TD3, "sac": sb3.SAC}[algo]
    model = cls("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, seed=seed,
                device="cpu", verbose=0, **kwargs)
    # SB3 seeds the action space and the env's first reset with the same seed, so the uniform
    # warm-up actions replay the env's own draws (on the toy env each was twice its goal, and
    # every episode succeeded at its first step): the action space gets a stream of its own
    stream = np.random.SeedSequence([seed, ACTION_STREAM])
    model.action_space.seed(int(stream.generate_state(1)[0]))
    return model


def policy_input(model: Any, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """What ``model.predict`` takes for raw observations ``batch`` (key -> (n, dim)): the batch
    normalised by the model's ``VecNormalize`` statistics when it trains under one (not updated
    here), else the batch itself."""
    norm = model.get_vec_normalize_env()
    return batch if norm is None else norm.normalize_obs(batch)


def test_session(model: Any, make_env: Any, seeds: Sequence[int]) -> dict[str, Any]:
    """One test session: an episode of the deterministic policy per seed, side by side.
    Returns the eval row without episode, env_steps and wall_s."""
    envs = [make_env() for _ in seeds]
    obs = [env.reset(seed=int(s))[0] for env, s in zip(envs, seeds, strict=True)]
    n = len(envs)
    done, success = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    returns, final = np.zeros(n), np.zeros(n)
    while not done.all():
        live = np.flatnonzero(~done)
        batch = {k: np.stack([obs[i][k] for i in live]) for k in obs[0]}
        actions, _ = model.predict(policy_input(model, batch), deterministic=True)
        for j, i in enumerate(live):
            obs[i], reward, terminated, truncated, info = envs[i].step(actions[j])
            returns[i] += reward
            success[i] = bool(info.get("is_success", False))
            done[i] = terminated or truncated
            final[i] = np.linalg.norm(obs[i]["achieved_goal"] - obs[i]["desired_goal"])
    for env in envs:
        env.close()
    return {"successes": int(success.sum()), "tests": n,
            "mean_return": round(float(returns.mean()), 6),
            "mean_final_distance_m": round(float(final.mean()), 6)}


def train(algo: str, env_id: str, env_kwargs: dict[str, Any], seed: int, episodes: int,
          eval_every: int, eval_episodes: int, hyperparams: dict[str, Any], out: Path,
          command: Sequence[str] = ()) -> list[dict[str, Any]]:
    """Train SB3's ``algo`` for ``episodes`` training episodes into the run folder ``out``;
    returns the eval rows (also in ``out/eval.csv``)."""
    import gymnasium

    from ddpg_her.runfolder import FORMAT, RunFolder, git_revision, versions
    from ddpg_her.vecenv import register_env

    folder = RunFolder(out)
    if folder.exists():
        raise ValueError(f"{out} exists; SB3 runs do not resume: choose another --out")
    name = register_env(env_id)

    def make_env() -> Any:
        return gymnasium.make(name, **env_kwargs)

    env = make_env()
    model = make_model(algo, env, hyperparams, seed)
    task = getattr(env.unwrapped, "task", None)
    spec = {
        "format": FORMAT, "env_id": env_id, "env_kwargs": env_kwargs,
        "task": task.to_dict() if task is not None else {}, "seed": seed,
        "agent": {"algo": f"sb3-{algo}", "episodes": episodes, "eval_every": eval_every,
                  "eval_episodes": eval_episodes, "sb3": hyperparams},
        "versions": versions(), "git": git_revision(), "command": list(command),
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    created = not folder.path.exists()
    folder.write_spec(spec)
    try:
        return _learn(model, env, make_env, folder, seed, episodes, eval_every,
                      eval_episodes)
    except BaseException:
        # nothing learnt is kept: leave no folder behind
        if not (folder.path / "eval.csv").exists():
            with contextlib.suppress(OSError):
                folder.spec_path.unlink()
                if created:
                    folder.path.rmdir()
        raise


def _learn(model: Any, env: Any, make_env: Any, folder: Any, seed: int, episodes: int,
           eval_every: int, eval_episodes: int) -> list[dict[str, Any]]:
    """`train`'s loop: learn with a test session every ``eval_every`` episodes."""
    from stable_baselines3.common.callbacks import BaseCallback

    from ddpg_her.trainer import EVAL_ENV_STREAM, stream_seed

    rows: list[dict[str, Any]] = []
    start = time.perf_counter()

    def session(episode: int) -> None:
        s = episode // eval_every
        row = test_session(model, make_env,
                           [stream_seed(seed, EVAL_ENV_STREAM, s, i) for i in range(eval_episodes)])
        rows.append({"episode": episode, **row, "env_steps": int(model.num_timesteps),
                     "wall_s": round(time.perf_counter() - start, 3)})
        folder.write_eval(rows)

    class Protocol(BaseCallback):
        """Counts training episodes; a test session every eval_every; stops at the budget."""

        def __init__(self) -> None:
            super().__init__()
            self.episode = 0

        def _on_step(self) -> bool:
            for done in self.locals["dones"]:
                if done:
                    self.episode += 1
                    if self.episode % eval_every == 0:
                        session(self.episode)
            return self.episode < episodes

    steps = episodes * (env.spec.max_episode_steps or 1000) + 1
    model.learn(total_timesteps=steps, callback=Protocol())
    return rows


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m analysis.sb3", description=__doc__.split("\n\n")[0])
    parser.add_argument("--algo", choices=ALGOS, default="ddpg",
                        help="Stable-Baselines3 algorithm (default: ddpg)")
    parser.add_argument("--region", required=True,
                        help="goal region, as ddpg_her.train --region (a name or a spec)")
    parser.add_argument("--joints", type=int, default=3,
                        help="controlled joints, 2..6 for UR5Reach-v0 (default: 3)")
    parser.add_argument("--task", action="append", default=[], metavar="KEY=VALUE",
                        help="a TaskSpec field, as ddpg_her.train --task; repeatable")
    parser.add_argument("--seed", type=int, default=0, help="seed, >= 0 (default: 0)")
    parser.add_argument("--episodes", type=int, default=1000,
                        help="training episodes, >= 1 (default: 1000)")
    parser.add_argument("--eval-every", type=int, default=100,
                        help="training episodes between test sessions, >= 1 (default: 100)")
    parser.add_argument("--eval-episodes", type=int, default=100,
                        help="test episodes per session, >= 1 (default: 100)")
    parser.add_argument("--hyperparams", type=Path, default=DEFAULT_HYPERPARAMS,
                        help=f"JSON hyperparameter file (default: {DEFAULT_HYPERPARAMS})")
    parser.add_argument("--env-id", default="UR5Reach-v0",
                        help="Gymnasium goal env id, or module:Id (default: UR5Reach-v0)")
    parser.add_argument("--out", type=Path, default=None,
                        help="run folder (default: runs/sb3-ALGO/REGION-jJOINTS/sSEED); must "
                             "not exist")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from ddpg_her.units import task_fields, task_option

    argv = list(sys.argv[1:] if argv is None else argv)
    parser = make_parser()
    args = parser.parse_args(argv)
    for flag, value, low in (("--seed", args.seed, 0), ("--episodes", args.episodes, 1),
                             ("--eval-every", args.eval_every, 1),
                             ("--eval-episodes", args.eval_episodes, 1)):
        if value < low:
            parser.error(f"{flag} must be >= {low}, got {value}")
    try:
        overrides = [task_option(t) for t in args.task]
        env_kwargs = task_fields(args.region, args.joints, overrides)
        hyperparams = load_hyperparams(args.hyperparams, args.algo)
    except (ValueError, argparse.ArgumentTypeError) as err:
        parser.error(str(err))
    from ddpg_her.train import register_envs

    register_envs(parser, [args.env_id])
    out = args.out or Path(f"runs/sb3-{args.algo}/{args.region}-j{args.joints}/s{args.seed}")
    try:
        rows = train(args.algo, args.env_id, env_kwargs, args.seed, args.episodes,
                     args.eval_every, args.eval_episodes, hyperparams, out,
                     command=["python", "-m", "analysis.sb3", *argv])
    except ValueError as err:
        parser.error(str(err))
    print(f"{out}: {rows[-1]['successes']} of {rows[-1]['tests']} at episode "
          f"{rows[-1]['episode']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
