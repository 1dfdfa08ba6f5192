"""The training program: the paper's protocol for every agent of a run as one stack on one
device (docs/design.md, "The training program").

All K agents, whatever their joint count, are one DDPG stack padded to six joints: inputs
``[theta, theta_dot, theta_ddot]`` of six joints and the two goal terms (24 values), actions of
six joints. An agent's weights are drawn at its own dimensions from its own seed and embedded;
the padded rows and columns start at zero and stay exactly zero (their inputs, actions and so
their gradients are zero), so each agent's real weights see what they see alone.

One episode is four bodies that read and write device tensors only: the training rollout
(goals drawn by rejection on the device, exploration, the env), the store (HER ``final``
relabelling, the ring buffer, the normaliser), the ``updates_per_episode`` updates, and every
``eval_every`` episodes the test session of ``eval_episodes`` deterministic episodes per
agent. On CUDA each body is captured once as a CUDA graph and replayed (``capture``); on the
CPU they run eagerly, the same code. The host reads the device once per test session (the
eval rows) and at checkpoints. Every random number is a pure function of (the agent's seed,
its stream, a counter) (`counter_uniform`), so an agent's run does not depend on who shares
its stack.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import torch

from ddpg_her.agent import DDPG
from ddpg_her.buffer import CounterSampler, Layout, ReplayBuffer, counter_draws, pack_tensors
from ddpg_her.checkpoints import run_spec
from ddpg_her.config import AgentConfig, Algo, HERStrategy
from ddpg_her.exploration import Explorer
from ddpg_her.logs import eval_rows
from ddpg_her.loop import Budget, Diverged, Loop, agents_of
from ddpg_her.normalizer import RunningNormalizer
from ddpg_her.spaces import goal_input
from ddpg_her.trainer import (
    EVAL_ENV_STREAM,
    EXPLORE_STREAM,
    INIT_STREAM,
    SAMPLE_STREAM,
    TRAIN_ENV_STREAM,
    stream_seed,
)
from ddpg_her.vecenv import register_env

STREAMS = "mix32-counter-1"
"""The version of the program's random streams, recorded in every spec.json (``program``):
goals, exploration and minibatches drawn by `counter_uniform` and `CounterSampler`."""

NJ = 6
"""Joints every agent is padded to."""

GOAL_DIM = 3
PADDED = Layout(3 * NJ + 2 * GOAL_DIM, NJ)
"""The stack's row layout: inputs of six joints plus the goal terms, six actions."""

WARMUP_REPLAYS = 2
"""Eager runs of a body before its CUDA graph is captured (torch.cuda.graph's documented
warm-up: they create lazily made state, such as cuBLAS handles and Adam's moments). They are
real runs, counted as such."""


def counter_uniform(keys: torch.Tensor, counter: torch.Tensor | int, slots: torch.Tensor
                    ) -> torch.Tensor:
    """Uniform float64 numbers in [0, 1) with 53 random bits: ``(keys (K, 1), counter,
    slots (S,)) -> (K, S)``, a pure function of its arguments (`counter_draws`)."""
    return (counter_draws(keys, counter, slots) >> 9).to(torch.float64) * 2.0**-53


class CounterDraws:
    """`ddpg_her.exploration.Explorer`'s draws from counter-based streams: agent k's numbers
    at step ``counter`` are a function of its key and the counter alone. The program draws a
    whole episode's numbers at once (`episode`, one batched call) and sets ``step`` before each
    call; each step reads its row. keys : (K,) 32-bit ints; device."""

    SLOTS = 2 * NJ
    """Numbers per agent and step: the most any draw takes (`normal`'s two per joint)."""

    def __init__(self, keys: Sequence[int], device: torch.device, steps: int = 1):
        self.device = device
        self.keys = torch.tensor(list(keys), dtype=torch.int64, device=device)[:, None, None]
        self._slots = torch.arange(self.SLOTS, dtype=torch.int64, device=device)
        self.table = torch.zeros(len(self.keys), steps, self.SLOTS, dtype=torch.float64,
                                 device=device)
        """(K, steps, SLOTS) float64: the numbers of the episode's steps."""
        self.step = 0

    def episode(self, counters: torch.Tensor) -> None:
        """Draw the numbers of the steps whose counters are ``counters (steps,)`` int64 on
        the device (step t: slots 0 .. `SLOTS` - 1 of counter ``counters[t]``), in place."""
        self.table.copy_(counter_uniform(self.keys, counters[:, None], self._slots))

    def _uniform(self, n: int) -> torch.Tensor:
        return self.table[:, self.step, :n]

    def drawing(self, active: torch.Tensor) -> torch.Tensor:
        return torch.ones_like(active)

    def uniform(self, rows: torch.Tensor, dim: int) -> torch.Tensor:
        return 2.0 * self._uniform(dim) - 1.0

    def normal(self, rows: torch.Tensor, dim: int) -> torch.Tensor:
        """Box-Muller on two uniforms per number (the first taken in (0, 1])."""
        u = self._uniform(2 * dim)
        return torch.sqrt(-2.0 * torch.log1p(-u[:, :dim])) * torch.cos(2.0 * math.pi * u[:, dim:])

    def coin(self, rows: torch.Tensor, p: float, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
        u = self._uniform(dim + 1)
        return u[:, 0] < p, 2.0 * u[:, 1:] - 1.0


class StackScale:
    """The affine map between actor units and each agent's action box, as device tensors
    (`ddpg_her.spaces.ActionScale` per agent, padded joints mapped to [-1, 1] so that 0 stays
    0). low, high : (K, 6) float64."""

    def __init__(self, low: torch.Tensor, high: torch.Tensor):
        self.low, self.high, self.dim = low, high, low.shape[-1]

    def _box(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        shape = (self.low.shape[0],) + (1,) * (x.ndim - 2) + (self.dim,)
        return self.low.reshape(shape), self.high.reshape(shape)

    def to_env(self, u: torch.Tensor) -> torch.Tensor:
        """u : (K, ..., 6) in [-1, 1] -> (K, ..., 6) float64 in the box."""
        low, high = self._box(u)
        return low + (u.to(torch.float64) + 1.0) * 0.5 * (high - low)

    def to_actor(self, a: torch.Tensor) -> torch.Tensor:
        low, high = self._box(a)
        return (a.to(torch.float64) - low) / (0.5 * (high - low)) - 1.0


def input_index(n: int) -> list[int]:
    """Where an agent with ``n`` joints finds its input ``x`` (length 3 n + 6) in the padded
    input (length 24): its theta, theta_dot, theta_ddot blocks at 0, 6, 12, the goal terms
    after."""
    return [b * NJ + j for b in range(3) for j in range(n)] + list(range(3 * NJ, PADDED.in_dim))


def row_index(n: int) -> list[int]:
    """Where a packed row of an agent with ``n`` joints (`Layout` of its own dims) lies in a
    padded row: x, u, r, x2, terminated."""
    x, i = input_index(n), PADDED.in_dim
    return x + [i + j for j in range(n)] + [i + NJ] + [i + NJ + 1 + c for c in x] \
        + [PADDED.width - 1]


PARAMETER_AXES = {"actor": {"l1.weight": (0, "in"), "l3.weight": (1, "act"),
                            "l3.bias": (1, "act")},
                  "critic": {"l1.weight": (0, "in"), "l2.weight": (0, "hidden+act")}}
"""The padded axis of each parameter that has one (per network: parameter -> (axis of the
per-agent tensor, which index)); every other parameter is the same at any joint count."""


def _index(which: str, n: int, hidden: int) -> list[int]:
    return {"in": input_index(n), "act": list(range(n)),
            "hidden+act": list(range(hidden)) + [hidden + j for j in range(n)]}[which]


def _network(name: str) -> str:
    return "actor" if name.startswith("actor") else "critic"


def _remapped(state: dict[str, Any], base: dict[str, Any], move: Callable[..., torch.Tensor],
              keep: Callable[[torch.Tensor], torch.Tensor]) -> dict[str, Any]:
    """A copy of ``base`` whose networks, optimisers and normaliser are ``state``'s, each tensor
    with a padded axis as ``move(v, axis, which, (network, parameter) or None for the
    normaliser)`` (`PARAMETER_AXES`), every other one as ``keep(v)``."""
    out = dict(base)
    for name in ("actor", "critic", "actor_target", "critic_target"):
        net = _network(name)
        out[name] = {p: move(v, *PARAMETER_AXES[net][p], (name, p))
                     if p in PARAMETER_AXES[net] else keep(v) for p, v in state[name].items()}
    for name in ("actor_opt", "critic_opt"):
        net = _network(name)
        axes = [PARAMETER_AXES[net].get(p) for p in _PARAMS]
        # Adam's moments are shaped as their parameters (a fresh optimiser has none yet)
        out[name] = {i: {key: move(v, *axes[i], (net, _PARAMS[i]))
                         if axes[i] is not None and v.ndim > 0 else keep(v)
                         for key, v in entry.items()} for i, entry in state[name].items()}
    out["normalizer"] = {key: move(v, 0, "in", None) if v.ndim > 0 else keep(v)
                         for key, v in state["normalizer"].items()}
    return out


_PARAMS = ("l1.weight", "l1.bias", "l2.weight", "l2.bias", "l3.weight", "l3.bias")
"""The parameters of a network in the order of its optimiser's state entries."""


def unpad_state(state: dict[str, Any], n: int, hidden: int) -> dict[str, Any]:
    """An agent's state (`DDPG.agent_state` of the padded stack) at its own dims: what a run
    of ``n`` joints trained alone holds (so ``ddpg_her.load`` reads it)."""
    return _remapped(state, state, lambda v, axis, which, _: v.index_select(
        axis, torch.tensor(_index(which, n, hidden))), lambda v: v)


def pad_state(state: dict[str, Any], padded: dict[str, Any], n: int, hidden: int
              ) -> dict[str, Any]:
    """Inverse of `unpad_state`: ``state`` (an agent's own dims) written into a copy of
    ``padded`` (an agent state of the padded stack, its zeros where the agent has no joint)."""
    def put(v: torch.Tensor, axis: int, which: str, key: tuple[str, str] | None) -> torch.Tensor:
        target = torch.zeros(PADDED.in_dim, dtype=v.dtype) if key is None else \
            torch.zeros_like(padded[key[0]][key[1]])
        return target.index_copy_(axis, torch.tensor(_index(which, n, hidden)), v.to(target))

    return _remapped(state, padded, put, torch.Tensor.clone)


class DeviceNormalizer(RunningNormalizer):
    """`RunningNormalizer` whose float64 sums stay on the device: `update_rows` adds a masked
    batch of every agent at once and refreshes the mean and std there, reading nothing back.
    `state` and `load_state` keep `RunningNormalizer`'s format."""

    def __init__(self, k: int, dim: int, **kwargs: Any):
        super().__init__(k, dim, **kwargs)
        dev = self.mean.device
        self.count_t = torch.zeros(k, dtype=torch.float64, device=dev)
        self.sum_t = torch.zeros(k, dim, dtype=torch.float64, device=dev)
        self.sumsq_t = torch.zeros(k, dim, dtype=torch.float64, device=dev)

    def update_rows(self, x: torch.Tensor, valid: torch.Tensor) -> None:
        """Add the rows ``x (K, L, dim)`` where ``valid (K, L)`` to each agent's sums."""
        x = torch.where(valid[..., None], x.to(torch.float64), 0.0)
        self.count_t += valid.sum(1)
        self.sum_t += x.sum(1)
        self.sumsq_t += (x * x).sum(1)
        if self.enabled:
            n = self.count_t.clamp(min=1.0)[:, None]
            mean = self.sum_t / n
            var = (self.sumsq_t / n - mean * mean).clamp(min=0.0)
            seen = (self.count_t > 0)[:, None]
            self.mean[:, 0] = torch.where(seen, mean, self.mean[:, 0].double()).to(self.mean)
            self.std[:, 0] = torch.where(seen, var.sqrt().clamp(min=self.eps),
                                         self.std[:, 0].double()).to(self.std)

    def state(self, k: int) -> dict[str, torch.Tensor]:
        return {"count": self.count_t[k].cpu(), "sum": self.sum_t[k].cpu().clone(),
                "sumsq": self.sumsq_t[k].cpu().clone()}

    def load_state(self, k: int, state: dict[str, torch.Tensor]) -> None:
        self.count_t[k] = float(state["count"])
        self.sum_t[k] = torch.as_tensor(state["sum"]).to(self.sum_t)
        self.sumsq_t[k] = torch.as_tensor(state["sumsq"]).to(self.sumsq_t)
        valid = torch.zeros(self.k, 0, dtype=torch.bool, device=self.sum_t.device)
        self.update_rows(torch.zeros(self.k, 0, self.dim, device=self.sum_t.device), valid)


class PaddedBuffer:
    """The stack's `ReplayBuffer` seen at each agent's own row layout, for the run folders'
    buffer chunks (`RunFolders.save` and `restore_buffer` call `since`, `put`, `total`)."""

    def __init__(self, buffer: ReplayBuffer, joints: Sequence[int]):
        self.buffer = buffer
        self.index = [torch.tensor(row_index(n), device=buffer.rows.device) for n in joints]

    @property
    def total(self) -> np.ndarray:
        return self.buffer.total

    def since(self, k: int, start: int) -> tuple[int, np.ndarray]:
        first, rows = self.buffer.since(k, start)
        return first, rows[:, self.index[k].cpu().numpy()]

    def put(self, k: int, start: int, rows: np.ndarray) -> None:
        padded = torch.zeros(len(rows), PADDED.width, dtype=self.buffer.rows.dtype,
                             device=self.buffer.rows.device)
        padded[:, self.index[k]] = torch.as_tensor(rows).to(padded)
        self.buffer.put(k, start, padded)


class Graphed:
    """``body()`` run eagerly, or on CUDA (``capture``) after `WARMUP_REPLAYS` eager runs
    captured once as a CUDA graph and replayed: the body must read and write only tensors
    that live as long as this object, and no host value that changes."""

    def __init__(self, body: Callable[[], None], capture: bool):
        self.body, self.capture, self.runs = body, capture, 0
        self.graph: torch.cuda.CUDAGraph | None = None
        self.replays = 0

    def __call__(self) -> None:
        if not self.capture:
            self.body()
            return
        if self.graph is None and self.runs < WARMUP_REPLAYS:
            side = torch.cuda.Stream()
            side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(side):
                self.body()
            torch.cuda.current_stream().wait_stream(side)
            self.runs += 1
            return
        if self.graph is None:
            self.graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(self.graph):
                self.body()
        self.graph.replay()
        self.replays += 1


class Program(Loop):
    """Trains K DDPG + HER agents, agent k on ``env_kwargs[k]`` with ``seeds[k]`` into
    ``run_dirs[k]``, as one stack on ``device`` (see the module docstring).

    Parameters
    ----------
    env_id : str
        A goal env with a stack twin (``UR5Reach-v0``).
    env_kwargs : K dicts
        Each agent's task (its env keywords); tasks may differ in region, joint count, start
        pose and penalty unit (`envs.stackreach.PER_COPY_FIELDS`).
    config : AgentConfig
        DDPG (``algo=ddpg``) without batch normalisation or ensemble, HER ``final`` or
        ``none``.
    seeds, run_dirs : K ints (distinct per task), K distinct folders.
    capture : bool, optional
        CUDA graphs of the four bodies (default: on CUDA).
    tf32 : bool
        Let CUDA's matrix products round their operands to TF32 (process-wide; recorded).
    dynamics : callable, optional
        The arm of the stack twin (its ``dynamics``; the tests give stand-ins).
    window, budget : bool, Budget, optional
        A run for one GPU window (spec.json's ``program.window``) and its time budget, as
        `ddpg_her.loop.Loop` says.
    fused : bool, optional
        Step the rollouts through `ddpg_her.program_kernels` (Triton; default: on CUDA with
        the stack's own arm; on the CPU it needs ``TRITON_INTERPRET=1``) instead of the eager
        ops that define them.
    """

    desc = "program"

    def __init__(self, env_id: str, env_kwargs: Sequence[dict[str, Any]], config: AgentConfig,
                 seeds: Sequence[int], run_dirs: Sequence[str | Path], *, resume: bool = False,
                 device: str = "cpu", dtype: torch.dtype = torch.float32, progress: bool = True,
                 command: Sequence[str] | None = None, capture: bool | None = None,
                 tf32: bool = False, dynamics: Callable[..., Any] | None = None,
                 window: bool = False, budget: Budget | None = None,
                 fused: bool | None = None):
        per_agent, seeds = agents_of(env_kwargs, seeds, run_dirs)
        check(env_id, per_agent, config, device, tf32, dtype)
        self.device = torch.device(device)
        self.capture = self.device.type == "cuda" if capture is None else bool(capture)
        if self.capture and self.device.type != "cuda":
            raise ValueError(f"capture needs a CUDA device; got {self.device}")
        if self.device.type == "cuda":
            torch.backends.cuda.matmul.allow_tf32 = bool(tf32)
        self.config, self.seeds, self.k = config, seeds, len(seeds)
        self.dtype, self.progress = dtype, progress
        m, k = config.eval_episodes, self.k
        twin = register_env(env_id)
        make = lambda n: gymnasium.make_vec(  # noqa: E731
            stack_twin(twin), num_envs=n, vectorization_mode="vector_entry_point",
            tasks=per_agent, device=self.device, dynamics=dynamics)
        self.env, self.eval_env = make(k), make(k * m)
        env = self.env
        # the kernels drive the stack's own arm (a stand-in has no kernel_step: eager)
        self.fused = (self.device.type == "cuda" and hasattr(env.dynamics, "kernel_step")) \
            if fused is None else bool(fused)
        self.T = env.task.max_episode_steps
        self.joints = [t.n_joints for t in env.tasks]
        self.act_mask = env.joint_mask.to(torch.float64)
        low = torch.where(env.joint_mask, env.action_low, -1.0)
        high = torch.where(env.joint_mask, env.action_high, 1.0)
        self.scale = StackScale(low, high)
        self.eval_scale = StackScale(low.repeat_interleave(m, 0), high.repeat_interleave(m, 0))

        # the agents: drawn at their own dims from their own seeds, embedded with zeros
        self.agent = DDPG(config, PADDED.in_dim, PADDED.act_dim, dtype=dtype,
                          device=self.device,
                          init_generators=[torch.Generator() for _ in seeds])
        self.agent.normalizer = DeviceNormalizer(
            k, PADDED.in_dim, eps=config.norm_eps, clip=config.obs_clip,
            enabled=config.normalize_obs, dtype=dtype, device=self.device)
        self.hidden = config.hidden_sizes[0]
        self._embed_initial_weights()
        self.buffer = ReplayBuffer(k, config.buffer_size, PADDED, dtype=dtype, device=self.device)
        self.chunks = PaddedBuffer(self.buffer, self.joints)
        self.sampler = CounterSampler([stream_seed(s, SAMPLE_STREAM) for s in seeds], self.device)
        self.agent.capturable()

        key = lambda stream: torch.tensor(  # noqa: E731
            [stream_seed(s, stream) for s in seeds], dtype=torch.int64, device=self.device)
        self.train_keys, self.eval_keys = key(TRAIN_ENV_STREAM), key(EVAL_ENV_STREAM)[:, None]
        self.draws = CounterDraws([stream_seed(s, EXPLORE_STREAM) for s in seeds], self.device,
                                  env.task.max_episode_steps)
        self.explorer = Explorer(config, self.draws, k, NJ)
        d, task = env.dynamics, env.task
        self._params = [torch.tensor(v, dtype=torch.float64, device=self.device) for v in (
            [config.exploration_rate, config.ou_theta, 2.0 * math.pi],
            [getattr(d, "_w_to_v", 0.0), getattr(d, "_w_to_accel", 0.0), task.success_radius,
             task.success_reward, task.distance_weight, task.action_weight,
             float(task.terminate_on_success), config.obs_clip])]
        self._allocate()

        self._finite = torch.ones((), dtype=torch.bool, device=self.device)
        self.specs = [{"program": {"streams": STREAMS,
                                   "matmul": "tf32" if tf32 else "float32",
                                   **({"window": True} if window else {})},
                       **run_spec(env_backend="program", env_id=env_id,
                                  env_kwargs=per_agent[i], task=env.tasks[i].to_dict(),
                                  seed=seeds[i], config=config, dims=self._dims(i),
                                  command=command)} for i in range(k)]
        self._open(run_dirs, resume, window, budget)
        if self.device.type == "cpu":  # after the record: the flush reaches Python's floats
            torch.set_flush_denormal(config.flush_denormals)
        self._bodies = {
            "warm": Graphed(lambda: self._train_episode(warm=True), self.capture),
            "act": Graphed(lambda: self._train_episode(warm=False), self.capture),
            "learn": Graphed(self._learn, self.capture),
            "test": Graphed(self._test_session, self.capture)}

    # ------------------------------------------------------------------ set-up
    def _dims(self, k: int) -> dict[str, Any]:
        n, t = self.joints[k], self.env.tasks[k]
        low, high = self.env.action_low[k, :n].tolist(), self.env.action_high[k, :n].tolist()
        return {"obs_dim": 3 * n, "goal_dim": GOAL_DIM, "act_dim": n, "action_low": low,
                "action_high": high, "max_episode_steps": t.max_episode_steps}

    def _embed_initial_weights(self) -> None:
        """Agent k's weights as `DDPG` draws them at k's own dims from ``stream_seed(seed,
        INIT_STREAM)``, embedded in the padded stack (zeros elsewhere)."""
        padded = [self.agent.agent_state(i) for i in range(self.k)]
        states = []
        for i, (seed, n) in enumerate(zip(self.seeds, self.joints, strict=True)):
            init = torch.Generator().manual_seed(stream_seed(seed, INIT_STREAM))
            alone = DDPG(self.config, 3 * n + 2 * GOAL_DIM, n, dtype=self.dtype,
                         init_generators=[init])
            states.append(pad_state(alone.agent_state(0), padded[i], n, self.hidden))
        self.agent.load_agent_states(states)

    def _allocate(self) -> None:
        """The episode tensors the bodies write (fixed addresses, for the graphs)."""
        k, m, T, dev = self.k, self.config.eval_episodes, self.T, self.device
        f64 = {"dtype": torch.float64, "device": dev}
        self.obs = torch.zeros(k, T + 1, 3 * NJ, **f64)
        self.achieved = torch.zeros(k, T + 1, GOAL_DIM, **f64)
        self.action = torch.zeros(k, T, NJ, **f64)
        self.reward = torch.zeros(k, T, **f64)
        self.terminated = torch.zeros(k, T, dtype=torch.bool, device=dev)
        self.length = torch.zeros(k, dtype=torch.int64, device=dev)
        self.success = torch.zeros(k, dtype=torch.bool, device=dev)
        self.env_steps = torch.zeros(k, dtype=torch.int64, device=dev)
        self.total = torch.zeros(k, dtype=torch.int64, device=dev)
        self.episode_t = torch.zeros((), dtype=torch.int64, device=dev)
        self.loss_sum = torch.zeros(2, k, dtype=torch.float64, device=dev)
        self.logged = torch.zeros(3, k * m, **f64)
        self._slots = torch.arange(self.env.proposals * NJ, dtype=torch.int64, device=dev)
        self._eval_index = torch.arange(m, dtype=torch.int64, device=dev)
        self._all = torch.ones(k, dtype=torch.bool, device=dev)
        self._all_eval = torch.ones(k * m, dtype=torch.bool, device=dev)
        self._t = torch.arange(T, device=dev)
        self._agents = torch.arange(k, device=dev)[:, None]
        self._slot = torch.arange(2 * T, device=dev)

    # ------------------------------------------------------------------ the bodies
    def _goal_uniforms(self, keys: torch.Tensor, counter: torch.Tensor
                       ) -> Callable[[int, int], torch.Tensor]:
        """The goal draws' numbers: proposals ``first .. first + count - 1`` of copy b,
        ``(B, count, 6)``, from the stream (keys[b], counter[b]) (slot 6 p + j: joint j of
        proposal p), every proposal's drawn at once."""
        keys, counter = keys[:, None], counter[:, None] if counter.ndim else counter
        u = counter_uniform(keys, counter, self._slots).reshape(len(keys), -1, NJ)
        return lambda first, count: u[:, first:first + count]

    def _rollout(self, env: Any, scale: StackScale, keys: torch.Tensor, counter: torch.Tensor,
                 policy: Callable[[torch.Tensor, torch.Tensor, int], torch.Tensor],
                 store: bool) -> tuple[torch.Tensor, ...]:
        """One episode in every copy of ``env`` from fresh goals, all ``T`` steps (copies
        whose episode ended are stepped and ignored). Returns length, success, the final
        achieved goal and goal, and the return; with ``store`` fills the episode tensors."""
        env.reset_where(self._all if env is self.env else self._all_eval,
                        env.draw_goals(self._goal_uniforms(keys, counter)))
        goal = env.goal.clone()
        obs, ag = env.observation()
        b = env.num_envs
        active = torch.ones(b, dtype=torch.bool, device=self.device)
        length = torch.zeros(b, dtype=torch.int64, device=self.device)
        success = torch.zeros(b, dtype=torch.bool, device=self.device)
        ret = torch.zeros(b, dtype=torch.float64, device=self.device)
        if store:
            self.obs[:, 0], self.achieved[:, 0] = obs, ag
        stop = env.task.terminate_on_success
        final = ag
        if self.fused:
            return self._fused_steps(env, scale, policy, goal, obs, ag, active, length,
                                     success, ret, final.clone(), store)
        for t in range(self.T):
            u = policy(goal_input(obs, ag, goal), active, t)
            action = scale.to_env(u)
            reward, succ = env.step(action)
            obs, ag = env.observation()
            term = succ & stop
            if store:
                self.obs[:, t + 1], self.achieved[:, t + 1] = obs, ag
                self.action[:, t] = torch.where(active[:, None], action, 0.0)
                self.reward[:, t], self.terminated[:, t] = reward, term
            ret += torch.where(active, reward, 0.0)
            final = torch.where(active[:, None], ag, final)
            length += active
            success = torch.where(active, succ, success)
            active = active & ~(term | (env.elapsed >= self.T))
        return length, success, goal, ret, final

    def _fused_steps(self, env: Any, scale: StackScale, policy: Any, goal: torch.Tensor,
                     obs: torch.Tensor, ag: torch.Tensor, *state: Any) -> tuple[torch.Tensor, ...]:
        """`_rollout`'s steps through `ddpg_her.program_kernels`: per step the actor (none in
        warm-up), `explore`, the arm kernel, `settle`. ``policy`` here is (noise kind, the
        actor of the normalised inputs (K, M, 24) or None, the joint mask (B, 6) float64);
        ``state``: active, length, success, ret, final, store."""
        from ddpg_her import program_kernels as fused

        (kind, actor, mask), (active, length, success, ret, final, store) = policy, state
        k, m, normalizer = self.k, env.num_envs // self.k, self.agent.normalizer
        x = normalizer(goal_input(obs, ag, goal).to(self.dtype).view(k, m, -1))
        x = x.reshape(env.num_envs, -1).contiguous()
        mu = torch.zeros(k, m, NJ, dtype=self.dtype, device=self.device)
        for t in range(self.T):
            if actor is not None:
                mu = actor(x.view(k, m, -1))
            fused.explore(kind, mu, self.draws.table[:, t], self.explorer.ou, self._params[0],
                          mask, scale, env, active, self.action[:, t] if store else None)
            env.dynamics.kernel_step()
            rows = (self.obs[:, t + 1], self.achieved[:, t + 1], self.reward[:, t],
                    self.terminated[:, t]) if store else None
            fused.settle(env, mask, active, ret, final, length, success, rows, x, normalizer,
                         m, self._params[1], self.T)
        return length, success, goal, ret, final

    def _train_episode(self, warm: bool) -> None:
        """The training episode of every agent (uniform actions while ``warm``), stored."""
        agent, explorer, draws = self.agent, self.explorer, self.draws
        explorer.reset()
        draws.episode(self.episode_t * self.T + self._t)

        def policy(x: torch.Tensor, active: torch.Tensor, t: int) -> torch.Tensor:
            mu = torch.zeros(self.k, NJ, dtype=torch.float64, device=self.device) if warm \
                else agent.act(x[:, None].to(self.dtype))[:, 0].double()
            draws.step = t
            return explorer(mu, active, uniform=warm) * self.act_mask

        if self.fused:
            policy = ("uniform" if warm else self.config.exploration.value,
                      None if warm else agent.actor, self.act_mask)
        length, success, goal, _, _ = self._rollout(
            self.env, self.scale, self.train_keys, self.episode_t, policy, store=True)
        self.length.copy_(length)
        self.success.copy_(success)
        self.env_steps += length
        self._store(goal)
        self.episode_t += 1

    def _store(self, goal: torch.Tensor) -> None:
        """The episode's transitions and its HER copy into the ring buffer, and their inputs
        into the normaliser: the rows `ddpg_her.collect.Collector.train_episode` writes."""
        k, T, env = self.k, self.T, self.env
        length = self.length
        rows = pack_tensors(self.obs, self.achieved, goal, self.action, self.reward,
                            self.terminated, self.scale)
        if self.config.her_strategy is HERStrategy.FINAL:
            her_goal = self.achieved[self._agents[:, 0], length]          # (K, 3)
            goals = her_goal[:, None].expand(k, T, GOAL_DIM)
            inside = self._t < length[:, None]
            term = env.success(self.achieved[:, 1:], goals) & env.task.terminate_on_success \
                & inside
            first = torch.where(term, self._t, T).amin(-1) + 1
            her_length = torch.minimum(first, length)
            her_term = term & (self._t < her_length[:, None])
            reward = env.reward(self.achieved[:, 1:], goals, self.action)
            her = pack_tensors(self.obs, self.achieved, her_goal, self.action, reward, her_term,
                               self.scale)
        else:
            her_length = torch.zeros_like(length)
            her = torch.zeros_like(rows)
        both = torch.cat([rows, her], 1)                                    # (K, 2T, width)
        s = self._slot[None]
        real, copy = s < length[:, None], (s >= length[:, None]) & (
            s < (length + her_length)[:, None])
        source = torch.where(real, s, torch.where(copy, T + s - length[:, None], 0))
        new = both.gather(1, source[..., None].expand_as(both))
        pos = (self.total[:, None] + s) % self.buffer.capacity
        valid = (real | copy)
        old = self.buffer.rows[self._agents, pos]
        self.buffer.rows[self._agents, pos] = torch.where(valid[..., None], new, old)
        self.agent.normalizer.update_rows(new[..., :PADDED.in_dim], valid)
        self.total += length + her_length
        torch.clamp(self.total, max=self.buffer.capacity, out=self.buffer.filled)

    def _learn(self) -> None:
        """``updates_per_episode`` updates of every agent on minibatches of its own stream."""
        self.loss_sum.zero_()
        for batch in self.sampler.samples(self.buffer, self.config.batch_size,
                                          self.config.updates_per_episode):
            self.agent.update(*batch, loss_sum=self.loss_sum)

    def _test_session(self) -> None:
        """``eval_episodes`` deterministic episodes per agent; writes `logged` (success,
        return, final distance (m) of each, agent-major). Session s's goals: the eval
        stream's counter s m + i for test episode i."""
        m = self.config.eval_episodes
        counter = (self.episode_t // self.config.eval_every * m + self._eval_index).repeat(self.k)
        keys = self.eval_keys.repeat_interleave(m, 0)[:, 0]

        def policy(x: torch.Tensor, active: torch.Tensor, t: int) -> torch.Tensor:
            return self.agent.act(x.reshape(self.k, m, -1).to(self.dtype)).reshape(
                self.k * m, NJ).double() * self.act_mask.repeat_interleave(m, 0)

        if self.fused:
            policy = ("none", self.agent.actor, self.act_mask.repeat_interleave(m, 0))
        _, success, goal, ret, final = self._rollout(self.eval_env, self.eval_scale, keys,
                                                     counter, policy, store=False)
        self.logged[0] = success.double()
        self.logged[1] = ret
        self.logged[2] = torch.linalg.vector_norm(final - goal, dim=-1)

    # ------------------------------------------------------------------ the engine's hooks
    def _train(self, warm: bool) -> None:
        self._bodies["warm" if warm else "act"]()

    def _updates(self) -> None:
        self._bodies["learn"]()
        self.sampler.updates += self.config.updates_per_episode
        self._finite &= torch.isfinite(self.loss_sum).all()

    def evaluate(self) -> list[dict[str, Any]]:
        """The test session (`_test_session`) and its eval rows."""
        self._bodies["test"]()
        return self._read()

    def _read(self) -> list[dict[str, Any]]:
        """The eval rows of the test session and the counts (the one read of the interval),
        once the losses and goal draws are checked."""
        logged, steps, finite, misses = (self.logged.cpu().numpy(), self.env_steps.cpu().numpy(),
                                         bool(self._finite), int(self.env.goal_misses
                                                                 + self.eval_env.goal_misses))
        if not finite:
            raise Diverged(
                f"the networks diverged (a loss is not finite) between episodes "
                f"{self.episode - self.config.eval_every + 1} and {self.episode}; the last "
                "checkpoint written is from before")
        if misses:
            raise RuntimeError(f"{misses} goal draws found no goal among "
                               f"{self.env.proposals} proposals")
        return eval_rows(self.episode, self.config.eval_episodes, steps, logged[0] > 0.5,
                         logged[1], logged[2])

    def _saved_buffer(self) -> PaddedBuffer:
        self.buffer.total[:] = self.total.cpu().numpy()
        return self.chunks

    def _agent_state(self, k: int) -> dict[str, Any]:
        return {"agent": unpad_state(self.agent.agent_state(k), self.joints[k], self.hidden),
                "rng": {"streams": STREAMS, "sample_counter": self.sampler.state()}}

    def _load(self, episode: int, states: list[dict[str, Any]],
              chunks: list[list[tuple[int, Any]]]) -> None:
        padded = [self.agent.agent_state(i) for i in range(self.k)]
        self.agent.load_agent_states([pad_state(s["agent"], p, n, self.hidden)
                                      for s, p, n in zip(states, padded, self.joints, strict=True)])
        self.sampler.load_state(states[0]["rng"]["sample_counter"])
        self.folders.restore_buffer(episode, states, chunks, self.chunks)
        self.total.copy_(torch.from_numpy(self.buffer.total))
        self.env_steps.copy_(torch.tensor([s["env_steps"] for s in states]))
        self.episode_t.fill_(episode)


TEST_COPY_BYTES = 250_000
"""Host or device bytes per test episode copy at its peak (its env copy, the rollout's history
and the dynamics' scratch), an upper estimate (`check`; issue 41): a CPU test session of 2,000
farbox copies peaked 336 MiB above one of 200, 196 kB a copy (``/usr/bin/time -f %M python -m
ddpg_her.train --region farbox --env-backend program --episodes 1 --eval-every 1
--eval-episodes M ...``)."""


PARAMETER_COPIES = 12
"""Copies of each network parameter the program holds at its peak (`ddpg_her.agents.
check_memory`'s ``copies``; the other paths hold 6): --hidden-sizes 100000 30 peaked 466 MiB
above --hidden-sizes 8 8 on the CPU (1.1e7 parameters, 11 float32 copies; the command of
`TEST_COPY_BYTES` with --eval-episodes 1)."""


def check(env_id: str, tasks: Sequence[dict[str, Any]], config: AgentConfig,
          device: str | torch.device = "cpu", tf32: bool = False,
          dtype: torch.dtype = torch.float32) -> None:
    """Raise ValueError, before anything is allocated, when the program cannot train
    ``config`` on ``tasks`` (one env-keyword dict per agent) on ``device``: another algorithm
    than DDPG + HER final/none, an env without a stack twin, tasks that do not form one stack
    (`envs.stackreach.stack_tasks`: the stop contact, ...), a region the device cannot test (a
    mesh), ``cuda`` without a device, TF32 on the CPU, or a stack larger than the device's
    memory (`ddpg_her.agents.check_memory`, the test copies included). The one check of the
    program's inputs: `Program` calls it, and so do the dry runs (``ddpg_her.train_many``,
    ``analysis.sweep``), so they refuse what the real run refuses, with its message."""
    from ddpg_her.agents import check_memory
    from envs.stackreach import RegionBounds, stack_tasks
    from envs.task import task_sampler

    why = [f"--algo {config.algo.value}"] if config.algo is not Algo.DDPG else []
    why += ["--batch-norm"] if config.batch_norm else []
    why += ["--prioritized-replay"] if config.prioritized_replay else []
    why += [f"--ensemble {config.ensemble}"] if config.ensemble > 1 else []
    if config.her_strategy not in (HERStrategy.FINAL, HERStrategy.NONE):
        why.append(f"--her-strategy {config.her_strategy.value}")
    if why:
        raise ValueError(f"the training program trains DDPG + HER only: not with "
                         f"{', '.join(why)}")
    stack_twin(env_id)
    for task in {repr(t.to_dict()): t for t in stack_tasks(tasks)}.values():
        RegionBounds.of(task_sampler(task).region)
    from ddpg_her.units import check_device

    dev = torch.device(device)
    check_device(dev.type)
    if tf32 and dev.type != "cuda":
        raise ValueError("--tf32 is a CUDA setting; the CPU multiplies in float32 (drop "
                         "--tf32 or give --device cuda)")
    check_memory(config, PADDED, len(tasks), dtype, dev, test_copy_bytes=TEST_COPY_BYTES,
                 copies=PARAMETER_COPIES)


def stack_twin(env_id: str) -> str:
    """The id of ``env_id``'s stack twin (`envs.stackreach.StackReach`), registered."""
    import importlib

    envs = importlib.import_module("envs")
    twin = envs.STACK_TWINS.get(env_id)
    if twin is None:
        raise ValueError(f"{env_id} has no stack twin for the training program; ids that "
                         f"have one: {sorted(envs.STACK_TWINS)}")
    return register_env(twin)
