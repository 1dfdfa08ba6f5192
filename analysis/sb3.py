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
``examples/sb3_her_vecnormalize.json``. Every key and value is checked against what SB3 declares
before SB3 sees it (`check_hyperparams`). A run is not resumable: an existing folder is refused.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import datetime
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ddpg_her.config import Parser
from ur5kin.checks import COUNT, SEED, Combination, Kind, choice, holds, integer, kinds, number

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


SECTIONS = ("common", *ALGOS)
"""The sections of a hyperparameter file (besides comments, keys that start with ``_``)."""

OWN_KEYWORDS = {
    "seed": "--seed",
    "env": "--env-id, --region, --joints and --task",
    "policy": "analysis.sb3 itself (MultiInputPolicy)",
    "replay_buffer_class": "analysis.sb3 itself (HerReplayBuffer)",
    "device": "analysis.sb3 itself (cpu)",
    "verbose": "analysis.sb3 itself (0)",
    "action_noise": "the file's action_noise_std (Gaussian noise of that std)",
}
"""SB3 keyword arguments the command sets itself -> what sets them; a file giving one is
refused, as the command's value would silently win or clash."""

RECIPE_KEYS: dict[str, Any] = {"action_noise_std": float | None,
                               "vec_normalize": dict[str, Any] | None}
"""Keys of a section that this recipe reads itself (not SB3's): name -> expected type (null:
no noise, no normaliser)."""

SET_BY_SB3 = {
    "policy_kwargs": ("observation_space", "action_space", "lr_schedule", "use_sde"),
    "replay_buffer_kwargs": ("buffer_size", "observation_space", "action_space", "env",
                             "device", "n_envs", "optimize_memory_usage"),
    "vec_normalize": ("venv",),
}
"""Of each nested object's keyword arguments, those SB3 (or this recipe) passes itself."""

RANGES = kinds(
    (number(0, above=True), "learning_rate"), (number(0, 1), "gamma"),
    (number(0, 1, above=True), "tau"),
    (COUNT, "batch_size", "buffer_size", "policy_delay", "replay_buffer_kwargs.n_sampled_goal"),
    (integer(0), "learning_starts"), (number(0), "target_policy_noise", "target_noise_clip"),
    (Kind("an integer >= 1, or -1 (one per environment step)", lambda v: v == -1 or v >= 1),
     "gradient_steps"),
    (Kind("an integer >= 1 or a list [integer >= 1, 'step' or 'episode']",
          lambda v: COUNT.test(v) or (COUNT.test(v[0]) and v[1] in ("step", "episode"))),
     "train_freq"),
    (Kind("null or a number >= 0 (the std of the Gaussian action noise; 0 or null: none)",
          lambda v: v is None or v >= 0), "action_noise_std"),
    (choice(("future", "final", "episode")), "replay_buffer_kwargs.goal_selection_strategy"),
    (Kind("a list of integers >= 1 (units per layer), or an object of such lists",
          lambda v: all(COUNT.test(n) for layer in (v.values() if isinstance(v, dict) else [v])
                        for n in layer)), "policy_kwargs.net_arch"))
"""The ranges of the keywords whose type SB3 declares (`sb3_keywords`) and the recipe's own
(`RECIPE_KEYS`), ``section.key`` inside a nested object: a value of the right type out of its
range is refused in one line before SB3 sees it."""

COMBINATIONS: tuple[Combination, ...] = (
    ("batch_size", "at most buffer_size", lambda p: p.get("batch_size", 1) <= p.get(
        "buffer_size", math.inf)),
    ("learning_starts", "below buffer_size (the warm-up rows must fit)",
     lambda p: p.get("learning_starts", 0) < p.get("buffer_size", math.inf)),
)
"""What a keyword may be combined with: (keyword, the rule in words, the test of the merged
keywords)."""


def load_hyperparams_dict(data: dict[str, Any], algo: str) -> dict[str, Any]:
    """`load_hyperparams` of a file's content already read, checked by `check_hyperparams`.

    Raises
    ------
    ValueError
        When a section is missing or unknown, or a key or value is not one SB3's ``algo``
        takes (see `check_hyperparams`).
    """
    if not isinstance(data, dict):
        raise ValueError(f"expected a JSON object of sections {', '.join(SECTIONS)}; got "
                         f"{type(data).__name__}")
    unknown = [k for k in data if k not in SECTIONS and not str(k).startswith("_")]
    if unknown:
        raise ValueError(f"unknown section(s) {', '.join(map(repr, unknown))}; the sections "
                         f"are {', '.join(SECTIONS)} (and comments, keys that start with _)")
    if algo not in data:
        raise ValueError(f"no section {algo!r} (sections: {sorted(data)})")
    for name in ("common", algo):
        if not isinstance(data.get(name, {}), dict):
            raise ValueError(f"section {name!r} must be a JSON object of keyword arguments; "
                             f"got {data[name]!r:.80}")
    params = {**data.get("common", {}), **data[algo]}
    check_hyperparams(params, algo)
    return params


def sb3_keywords(algo: str) -> dict[str, dict[str, Any]]:
    """What SB3 itself declares: for ``algo``'s constructor and for each nested object of
    `SET_BY_SB3` (its policy, HerReplayBuffer, VecNormalize), keyword -> annotation, less the
    ones set for the user (`OWN_KEYWORDS`, `SET_BY_SB3`) and private ones."""
    import inspect

    import stable_baselines3 as sb3
    from stable_baselines3 import HerReplayBuffer
    from stable_baselines3.common.vec_env import VecNormalize

    cls = {"ddpg": sb3.DDPG, "td3": sb3.TD3, "sac": sb3.SAC}[algo]
    nested = {"": cls, "policy_kwargs": cls.policy_aliases["MultiInputPolicy"],
              "replay_buffer_kwargs": HerReplayBuffer, "vec_normalize": VecNormalize}
    out = {}
    for where, target in nested.items():
        own = SET_BY_SB3.get(where, tuple(OWN_KEYWORDS))
        out[where] = {name: p.annotation
                      for name, p in inspect.signature(target.__init__).parameters.items()
                      if name != "self" and not name.startswith("_") and name not in own
                      and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
    out[""].update(RECIPE_KEYS)
    return out


def check_hyperparams(params: dict[str, Any], algo: str) -> None:
    """Check the keyword arguments ``params`` (one section merged over ``common``) in our words
    before SB3 sees them: every key one SB3's ``algo`` takes (its constructor's keywords, the
    recipe's `RECIPE_KEYS`; inside ``policy_kwargs``, ``replay_buffer_kwargs`` and
    ``vec_normalize``, those of the policy, HerReplayBuffer and VecNormalize), none the
    command sets itself (`OWN_KEYWORDS`, `SET_BY_SB3`), and every value of the type SB3
    declares for it, as JSON can give it (a number for ``float``, an integer for ``int``, a
    list for a tuple), then the ranges of `RANGES` and the rules of `COMBINATIONS`.

    Raises
    ------
    ValueError
        Naming the key, and the allowed keys, the flag that sets it, or the value and the
        expected type.
    """
    keywords = sb3_keywords(algo)
    _check_keys(params, keywords[""], algo, "")
    for key, value in params.items():
        _check_value(key, value, keywords[""][key], algo)
        if key in SET_BY_SB3 and value is not None:
            _check_keys(value, keywords[key], algo, f"{key}.")
            for sub, subvalue in value.items():
                _check_value(f"{key}.{sub}", subvalue, keywords[key][sub], algo)
    flat = {**params, **{f"{key}.{sub}": v for key in SET_BY_SB3
                         for sub, v in (params.get(key) or {}).items()}}
    bad = [f"{name}={flat[name]!r:.80} (expected {kind.words})" for name, kind in RANGES.items()
           if name in flat and not holds(kind.test, flat[name])]
    bad = bad or [f"{name}={flat[name]!r} (expected {words})" for name, words, test
                  in COMBINATIONS if not holds(test, flat)]
    if bad:
        raise ValueError(f"{algo}: invalid hyperparameters: " + ", ".join(bad))


def _check_keys(params: dict[str, Any], allowed: dict[str, Any], algo: str, where: str
                ) -> None:
    """Refuse a key of ``params`` (at ``where``) that is not in ``allowed``."""
    for key in params:
        name = f"{where}{key}"
        if not where and key in OWN_KEYWORDS:
            raise ValueError(f"{algo}: {key} is set by {OWN_KEYWORDS[key]}; drop it from the "
                             "hyperparameter file")
        if where and key in SET_BY_SB3.get(where.rstrip("."), ()):
            raise ValueError(f"{algo}: {name} is set by SB3 itself (from the model's own "
                             "arguments); drop it from the hyperparameter file")
        if key not in allowed:
            raise ValueError(f"{algo}: unknown hyperparameter {name!r}; SB3's "
                             f"{algo.upper()} under this recipe takes "
                             f"{', '.join(where + k for k in sorted(allowed))}")


def _check_value(name: str, value: Any, hint: Any, algo: str) -> None:
    """Refuse ``value`` of the key ``name`` when JSON's value is not of SB3's type ``hint``."""
    fits, words = _json_form(hint)
    if not fits(value):
        raise ValueError(f"{algo}: {name} = {json.dumps(value)[:80]} ({_json_kind(value)}): "
                         f"expected {words}")


def _json_kind(value: Any) -> str:
    """The JSON type of a value read from JSON, in JSON's words."""
    if value is None:
        return "null"
    return {bool: "true/false", int: "an integer", float: "a number", str: "a string",
            list: "a list", dict: "an object"}.get(type(value), type(value).__name__)


def _json_form(hint: Any) -> tuple[Callable[[Any], bool], str]:
    """What JSON values fit SB3's annotation ``hint``: a test of a value read from JSON, and
    the forms in JSON's words. Any, and a keyword SB3 did not annotate, fit every value;
    classes JSON cannot give (a Callable, a torch module's class) fit none (`UNWRITABLE`)."""
    import inspect
    import types
    import typing

    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):  # a | b, Optional
        forms = [_json_form(m) for m in args]
        words = [w for _, w in forms if w != UNWRITABLE]
        return (lambda v: any(fits(v) for fits, _ in forms),
                " or ".join(dict.fromkeys(words)) or UNWRITABLE)
    if hint is Any or hint is inspect.Parameter.empty:
        return (lambda v: True), UNWRITABLE
    simple = {type(None): (lambda v: v is None, "null"),
              bool: (lambda v: isinstance(v, bool), "true or false"),
              int: (lambda v: isinstance(v, int) and not isinstance(v, bool), "an integer"),
              float: (lambda v: isinstance(v, int | float) and not isinstance(v, bool),
                      "a number"),
              str: (lambda v: isinstance(v, str), "a string"),
              dict: (lambda v: isinstance(v, dict), "an object"),
              list: (lambda v: isinstance(v, list), "a list")}
    bare = origin if origin in (dict, list) and not args else hint  # typing.Dict: dict
    if bare in simple:
        return simple[bare]
    if origin is dict:
        fits, words = _json_form(args[1])
        return (lambda v: isinstance(v, dict) and all(isinstance(k, str) and fits(x)
                                                      for k, x in v.items()),
                "an object" if args[1] is Any else f"an object whose values are {words}")
    if origin is list:
        fits, words = _json_form(args[0])
        return (lambda v: isinstance(v, list) and all(map(fits, v)),
                f"a list of {_plural(words)}")
    if origin is tuple:
        forms = [_json_form(a) for a in args]
        return (lambda v: isinstance(v, list) and len(v) == len(forms)
                and all(fits(x) for (fits, _), x in zip(forms, v, strict=True)),
                f"a list [{', '.join(w for _, w in forms)}]")
    return (lambda v: False), UNWRITABLE


UNWRITABLE = "a Python object, which a JSON file cannot give (leave it out)"
"""What `_json_form` says of an annotation no JSON value fits."""


def _plural(words: str) -> str:
    """'an integer' -> 'integers' (for `_json_form` of a list)."""
    return " or ".join(w.split(" ", 1)[1] + "s" if w.startswith(("a ", "an ")) else w
                       for w in words.split(" or "))


def make_model(algo: str, env: Any, hyperparams: dict[str, Any], seed: int) -> Any:
    """SB3's ``algo`` on ``env`` with its HerReplayBuffer and the file's hyperparameters."""
    import stable_baselines3 as sb3
    from stable_baselines3 import HerReplayBuffer
    from stable_baselines3.common.noise import NormalActionNoise

    check_hyperparams(hyperparams, algo)  # the library's way in is checked as the command's
    kwargs = copy.deepcopy(hyperparams)  # SB3 writes into policy_kwargs (SAC: use_sde)
    norm = kwargs.pop("vec_normalize", None)
    if norm is not None:
        # SB3's own input normaliser (ours keeps one per agent, clipped at +-5 std): the buffer
        # stores raw observations and normalises each sampled batch, relabelled goals included
        from stable_baselines3.common.monitor import Monitor
        from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

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
    """Train SB3's ``algo`` for ``episodes`` training episodes into the run folder ``out``, a test
    session every ``eval_every``; returns the eval rows (also in ``out/eval.csv``)."""
    import gymnasium
    from stable_baselines3.common.callbacks import BaseCallback

    from ddpg_her.runfolder import FORMAT, RunFolder, git_revision, versions
    from ddpg_her.trainer import EVAL_ENV_STREAM, stream_seed
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
    rows: list[dict[str, Any]] = []

    def session(episode: int) -> None:
        s = episode // eval_every
        row = test_session(model, make_env,
                           [stream_seed(seed, EVAL_ENV_STREAM, s, i) for i in range(eval_episodes)])
        rows.append({"episode": episode, **row, "env_steps": int(model.num_timesteps),
                     "wall_s": round(time.perf_counter() - start, 3)})
        folder.write_eval(rows)
        print(f"episode {episode}/{episodes}: {row['successes']}/{row['tests']} test goals, "
              f"{rows[-1]['wall_s']:.0f} s", file=sys.stderr, flush=True)

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

    created = not folder.path.exists()
    folder.write_spec(spec)
    try:
        start = time.perf_counter()
        steps = episodes * (getattr(task, "max_episode_steps", None)  # a UR5 task's, else the id's
                            or env.spec.max_episode_steps or 1000) + 1
        print(f"training {type(model).__name__} + HER into {folder.path}: {episodes} episodes, "
              f"a line per test session (every {eval_every})", file=sys.stderr, flush=True)
        model.learn(total_timesteps=steps, callback=Protocol())
        return rows
    except BaseException:
        # nothing learnt is kept: leave no folder behind
        if not (folder.path / "eval.csv").exists():
            with contextlib.suppress(OSError):
                folder.spec_path.unlink()
                if created:
                    folder.path.rmdir()
        raise


def make_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="python -m analysis.sb3", description=__doc__.split("\n\n")[0])
    parser.add_argument("--algo", choices=ALGOS, default="ddpg",
                        help="Stable-Baselines3 algorithm (default: ddpg)")
    parser.add_argument("--region", required=True,
                        help="goal region, as ddpg_her.train --region (a name or a spec)")
    parser.add_argument("--joints", type=int, default=3,
                        help="controlled joints, 2..6 for UR5Reach-v0 (default: 3)")
    parser.add_argument("--task", action="append", default=[], metavar="KEY=VALUE",
                        help="a TaskSpec field, as ddpg_her.train --task; repeatable")
    parser.add_argument("--seed", type=SEED.read, default=0, help="seed, >= 0 (default: 0)")
    parser.add_argument("--episodes", type=COUNT.read, default=1000,
                        help="training episodes, >= 1 (default: 1000)")
    parser.add_argument("--eval-every", type=COUNT.read, default=100,
                        help="training episodes between test sessions, >= 1 (default: 100)")
    parser.add_argument("--eval-episodes", type=COUNT.read, default=100,
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
    try:
        env_kwargs = task_fields(args.region, args.joints, [task_option(t) for t in args.task])
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
