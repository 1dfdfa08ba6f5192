"""B copies of the Reacher whose whole state lives in torch tensors on one device (issue 14):
:class:`TorchReach`, whose arm (:data:`DYNAMICS`), goals (:class:`GoalPool`, draws of the task's
own sampler stocked on the device), reward (:func:`envs.reward.reach_reward`, also for HER's
relabelling) and autoreset are tensor operations there, so that on a GPU a training step moves
no data between host and device.

Where the host is touched (each a device-to-host read, i.e. a synchronisation on CUDA):
``reset`` with a seed or for the first time (it fills the pool and checks the start pose), and
the goal pool's top-up, at most once every ``goal_pool`` calls of ``step`` or masked ``reset``.
Nothing else: ``step`` checks only shapes (host metadata), never values (a finiteness check
reads the device); its actions must be finite.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import gymnasium
import numpy as np
import torch
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode

from envs.physics.model import require_kernels
from envs.physics.torch_kernel import TorchDynamics
from envs.reward import ACTION_KEY, GOAL_DIM, goal_distance, reach_reward
from envs.spec import TaskSpec, make_task
from envs.task import (
    INFO_KEYS,
    action_bounds,
    action_penalty_scale,
    as_autoreset_mode,
    single_spaces,
    task_sampler,
)
from envs.vector import VectorReach, check_num_envs, copy_seeds, reset_options

if TYPE_CHECKING:
    from envs.physics.numba_torch import NumbaTorchDynamics

GOAL_SOURCES = ("batched", "per_copy")
"""How :class:`GoalPool` draws goals on the host: ``batched`` from one generator in one
vectorised sampler call (cheap); ``per_copy`` from one generator per copy, one sampler call per
goal, exactly as :class:`envs.batched.BatchedReach` does (copy i seeded ``seed + i`` gets the
same goals; about 0.6 ms a goal on the 2-core machine)."""

DYNAMICS = ("torch", "numba")
"""The arm dynamics of :class:`TorchReach`, named for their tool: ``torch``, the vectorised
tensor step (:class:`envs.physics.torch_kernel.TorchDynamics`, any device); ``numba``, the numba
kernels behind the same face (:class:`envs.physics.numba_torch.NumbaTorchDynamics`)."""

DEFAULT_POOL_DEPTH = 64
"""Goals stocked per copy; also the ``step`` calls between two top-ups at most."""


# ---------------------------------------------------------------------------- the goals
class GoalPool:
    """Goals for B copies, stocked on the device and drawn there without synchronisation.

    Copy i holds ``depth`` goals ``pool[i, cursor[i]:]``; :meth:`draw` hands the next one to
    every copy of a mask and advances its cursor, on the device. The host keeps a lower bound
    of the goals every copy has left (each draw takes at most one per copy) and tops the pool
    up before a draw could find it empty: it then reads the cursors (one synchronisation) and
    draws as many goals as were used, by the task's sampler.

    Exactness: every goal is a draw of the task's sampler (:func:`envs.task.task_sampler`), the
    same code and distribution as the numpy env's; ``per_copy`` also reproduces its sequence.

    Parameters
    ----------
    task : TaskSpec
    num_copies : int
        B.
    depth : int
        Goals stocked per copy (>= 1).
    source : {"batched", "per_copy"}
        :data:`GOAL_SOURCES`.
    device, dtype
        Of the pool.
    """

    def __init__(self, task: TaskSpec, num_copies: int, depth: int, source: str,
                 device: torch.device, dtype: torch.dtype) -> None:
        if not isinstance(depth, int | np.integer) or depth < 1:
            raise ValueError(f"goal_pool must be an integer >= 1 (goals per copy); got {depth!r}")
        if source not in GOAL_SOURCES:
            raise ValueError(f"goal_source must be one of {list(GOAL_SOURCES)}; got {source!r}")
        self.sampler = task_sampler(task)
        self.num_copies, self.depth, self.source = int(num_copies), int(depth), source
        self.device, self.dtype = device, dtype
        self._host = np.zeros((self.num_copies, self.depth, GOAL_DIM))
        self.pool = torch.zeros((self.num_copies, self.depth, GOAL_DIM), device=device,
                                dtype=dtype)
        self.cursor = torch.zeros(self.num_copies, dtype=torch.long, device=device)
        self._rngs: list[np.random.Generator] = []
        self._left = 0  # goals every copy surely has left

    def seed(self, seed: int | Sequence[int] | None) -> None:
        """New generators (``per_copy``: copy i from ``seed + i``, or from ``seed[i]`` given one
        seed per copy, as :meth:`envs.batched.BatchedReach.reset`; ``batched``: one from
        ``seed``; None: fresh entropy) and a full pool drawn from them."""
        if self.source == "per_copy":
            self._rngs = [seeding.np_random(None if s is None else int(s))[0]
                          for s in copy_seeds(seed, self.num_copies)]
        elif isinstance(seed, int | np.integer | None):
            self._rngs = [seeding.np_random(seed)[0]]
        else:
            raise ValueError(f"one seed per copy ({self.num_copies}) needs goal_source="
                             f"'per_copy'; got {len(seed)} seeds with {self.source!r}")
        self._host[:] = self._goals(np.full(self.num_copies, self.depth)).reshape(
            self._host.shape)
        self._upload()

    def _goals(self, counts: np.ndarray) -> np.ndarray:
        """``counts[i]`` new goals of copy i, stacked copy by copy, ``(sum, 3)`` m."""
        if self.source == "batched":
            return self.sampler.sample(int(counts.sum()), self._rngs[0]).goals
        rows = [self.sampler.sample(1, rng).goals[0] for rng, k in zip(self._rngs, counts,
                                                                        strict=True)
                for _ in range(k)]
        return np.array(rows).reshape(-1, GOAL_DIM)

    def _upload(self) -> None:
        self.pool.copy_(torch.as_tensor(self._host).to(dtype=self.dtype))
        self.cursor.zero_()
        self._left = self.depth

    def _top_up(self) -> None:
        """Replace the goals used since the last fill (reads the cursors: a sync on CUDA)."""
        used = self.cursor.cpu().numpy()
        fresh = iter(np.split(self._goals(used), np.cumsum(used)[:-1]))
        for i, k in enumerate(used):
            self._host[i] = np.concatenate([self._host[i, k:], next(fresh)])
        self._upload()

    def draw(self, mask: torch.Tensor, goal: torch.Tensor) -> None:
        """Write the next goal of every copy where ``mask (B,) bool`` into ``goal (B, 3)``, in
        place, and advance those cursors (on the device, unless a top-up is due)."""
        if not self._rngs:
            raise RuntimeError("GoalPool.draw before seed()")
        if self._left == 0:
            self._top_up()
        self._left -= 1
        nxt = self.pool.gather(1, self.cursor.view(-1, 1, 1).expand(-1, 1, GOAL_DIM))[:, 0]
        goal.copy_(torch.where(mask.unsqueeze(-1), nxt, goal))
        self.cursor.add_(mask.to(torch.long))


def make_tensor_dynamics(task: TaskSpec, num_copies: int, dynamics: str, device: Any,
                         dtype: Any, cuda_graph: bool = False
                         ) -> TorchDynamics | NumbaTorchDynamics:
    """The arm of :class:`TorchReach`: ``num_copies`` copies of ``task`` by ``dynamics`` (one of
    :data:`DYNAMICS`) on ``device``, state as tensors of ``dtype``.

    Raises
    ------
    ValueError
        For another ``dynamics``, ``cuda_graph`` with ``numba`` (its step is one launch
        already), or a device the chosen dynamics cannot run on here.
    """
    if dynamics == "torch":
        return TorchDynamics(task, num_copies, device=device, dtype=dtype, cuda_graph=cuda_graph)
    if dynamics != "numba":
        raise ValueError(f"dynamics must be one of {list(DYNAMICS)}; got {dynamics!r}")
    if cuda_graph:
        raise ValueError("cuda_graph=True records the torch step; dynamics='numba' is one "
                         "kernel launch per step already")
    from envs.physics.numba_kernel import available

    if not available():
        raise ValueError("dynamics='numba' needs numba (pip install numba); "
                         "dynamics='torch' runs without it")
    from envs.physics.numba_torch import NumbaTorchDynamics

    return NumbaTorchDynamics(task, num_copies, device=device, dtype=dtype)


def _seeds(seed: int | Sequence[int] | None) -> int | list[int] | None:
    """A reset's ``seed`` as an int, a list of ints or None; ValueError for anything else."""
    if isinstance(seed, Sequence):
        return [int(s) for s in seed]
    if seed is not None and not isinstance(seed, int | np.integer):
        raise ValueError(f"seed must be an int, a sequence of ints or None; got {seed!r}")
    return None if seed is None else int(seed)


# ---------------------------------------------------------------------------- the env
class TorchReach(VectorReach):
    """N copies of ``UR5Reach-v0`` as tensors on one device: BatchedReach with torch in and out.

    Given the same goals and actions, every step equals :class:`envs.batched.BatchedReach`'s
    (``dynamics="numba"``) to floating-point rounding (tested to 1e-9 in float64); with
    ``goal_source="per_copy"`` the same seed gives the same goals too.

    Spaces, reward, start and episode end are those of ``UR5Reach-v0``
    (:class:`envs.reach.UR5ReachEnv`, whose docstring documents them) with a leading ``(N,)``
    axis, as tensors on the device (the spaces stay numpy boxes, BatchedReach's). Where they
    differ: actions must be finite (unchecked: a check would read the device); the goals come
    from :class:`GoalPool`; the autoreset modes (:class:`envs.vector.VectorReach`'s, ``next_step``
    by default) step and reset every copy masked, never asking which ended (that would read the
    device), and ``same_step``'s ``info["final_obs"]`` / ``info["final_info"]`` are dicts of
    (N, ...) tensors with the masks ``info["_final_obs"]`` / ``info["_final_info"]``.

    Parameters
    ----------
    num_envs : int
        N.
    task : TaskSpec or its dict form, optional
        The task; ``**overrides`` change fields. Only the stop contact model.
    device : str or torch.device
        Where everything lives (``"cpu"``, ``"cuda"``).
    dtype : {"float64", "float32"}
    autoreset_mode : gymnasium.vector.AutoresetMode or str
    goal_source : {"batched", "per_copy"}
        :data:`GOAL_SOURCES`.
    goal_pool : int
        Goals stocked per copy (:class:`GoalPool`): a top-up (one sync) every this many steps
        at most.
    cuda_graph : bool
        Passed to :class:`envs.physics.torch_kernel.TorchDynamics` (``dynamics="torch"``
        only).
    dynamics : {"torch", "numba"}
        :data:`DYNAMICS`: the tensor step, or the fused CUDA kernel (``device="cuda"``). Both
        give the same rollouts to rounding (tested to 1e-9 in float64).

    ``info`` holds :data:`envs.task.INFO_KEYS` as (N, ...) tensors (``clearance`` from the
    plane check's exact heights), each with an all-True ``_key`` mask.
    """

    def __init__(self, num_envs: int = 1, task: TaskSpec | Mapping[str, Any] | None = None, *,
                 device: Any = "cpu", dtype: Any = "float64",
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 goal_source: str = "batched", goal_pool: int = DEFAULT_POOL_DEPTH,
                 cuda_graph: bool = False, dynamics: str = "torch",
                 **overrides: Any) -> None:
        num_envs = check_num_envs(num_envs)
        self.task = make_task(task, overrides)  # checked by its dynamics (envs.validate)
        require_kernels(self.task, "TorchReach")
        self.num_envs, self.autoreset_mode = num_envs, as_autoreset_mode(autoreset_mode)
        self.metadata = {"autoreset_mode": self.autoreset_mode}
        self.spec: Any = None  # set by gymnasium.make_vec
        # host-side metadata (numpy boxes, as BatchedReach's); values stay tensors
        self.single_observation_space, self.single_action_space = single_spaces(self.task)
        self.dynamics = make_tensor_dynamics(self.task, self.num_envs, dynamics, device, dtype,
                                             cuda_graph)
        self.device, self.dtype = self.dynamics.device, self.dynamics.dtype
        B, n, dev = self.num_envs, self.task.n_joints, self.device
        self.goals = GoalPool(self.task, B, goal_pool, goal_source, dev, self.dtype)
        self.dynamics.reset(self.task.start_q)  # checks the start pose once, on the host

        def t(x: Any) -> torch.Tensor:
            return torch.as_tensor(np.asarray(x, dtype=np.float64)).to(device=dev,
                                                                      dtype=self.dtype)

        low, high = action_bounds(self.task)
        self.action_low, self.action_high = t(low), t(high)
        self._penalty_scale = t(action_penalty_scale(self.task))
        self._start_q = t(self.task.start_q)
        self.goal = torch.zeros((B, GOAL_DIM), device=dev, dtype=self.dtype)
        self.action = torch.zeros((B, n), device=dev, dtype=self.dtype)
        self.elapsed = torch.zeros(B, dtype=torch.long, device=dev)
        self._ended = torch.zeros(B, dtype=torch.bool, device=dev)
        self._all = torch.ones(B, dtype=torch.bool, device=dev)
        self._started = False

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
        """Reset copies: all of them, or ``options["reset_mask"]`` ((N,) bool tensor).

        ``seed``: an int, or with ``goal_source="per_copy"`` one int per copy, reseeds the goal
        source (:meth:`GoalPool.seed`, whatever the mask) and refills the pool; None keeps it
        (fresh entropy on the first reset).
        ``options["goal"]``: ``(N, 3)`` m, goals for the copies reset (other rows ignored)
        instead of drawing them. The first reset must be of all copies.
        """
        options = reset_options(options, ("reset_mask", "goal"),
                                "{'reset_mask': (N,) bool tensor, 'goal': (N, 3) m}")
        mask = self._all
        if "reset_mask" in options:
            mask = torch.as_tensor(options["reset_mask"], device=self.device)
            if mask.shape != (self.num_envs,) or mask.dtype != torch.bool:
                raise ValueError(f"options['reset_mask'] must be ({self.num_envs},) bool; got "
                                 f"{tuple(mask.shape)} {mask.dtype}")
            if not self._started:
                raise ValueError("the first reset must reset every copy (no reset_mask)")
        if seed is not None or not self._started:
            self.goals.seed(_seeds(seed))
        self._reset_where(mask)
        if "goal" in options:
            goal = torch.as_tensor(options["goal"], device=self.device, dtype=self.dtype)
            if goal.shape != (self.num_envs, GOAL_DIM):
                raise ValueError(f"options['goal'] must be ({self.num_envs}, 3) goals (m, world "
                                 f"frame); got shape {tuple(goal.shape)}")
            self.goal.copy_(torch.where(mask.unsqueeze(-1), goal, self.goal))
        self._started = True
        self._ended.masked_fill_(mask, False)
        return self._observation(), self._info()

    def draw_goals(self, seed: int | Sequence[int]) -> torch.Tensor:
        """The goals ``(N, 3)`` m, world frame, that ``reset(seed=seed)`` starts the copies
        with, drawn alone: the goal source reseeded (:meth:`GoalPool.seed`) and its next goal
        taken for every copy, nothing else reset or stepped. For a merged batch
        (``ddpg_her.vecenv.TorchGoalVecEnv``): each group draws its goals here and hands them
        to the batch's env with ``reset(options={"goal": ...})``."""
        self.goals.seed(_seeds(seed))
        goal = torch.zeros_like(self.goal)
        self.goals.draw(self._all, goal)
        return goal

    # step: VectorReach.step, every value on the device. Raises ValueError when ``actions`` is
    # not (N, n), gymnasium.error.ResetNeeded before the first reset.
    _where = staticmethod(torch.where)

    def _checked_actions(self, actions: Any) -> torch.Tensor:
        if not self._started:
            raise gymnasium.error.ResetNeeded("step() before reset(): call reset() first")
        n = self.task.n_joints
        a = torch.as_tensor(actions, device=self.device)
        if a.shape != (self.num_envs, n) or a.is_complex():
            raise ValueError(f"actions must be a real ({self.num_envs}, {n}) tensor (the "
                             f"{self.task.control_mode} commands of joints 1..{n}); got shape "
                             f"{tuple(a.shape)}")
        return a

    def _advance(self, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        torch.clamp(actions.to(self.dtype), self.action_low, self.action_high, out=self.action)
        self.dynamics.step(self.action)
        self.elapsed.add_(1)
        distance = self._distance()
        reward = reach_reward(distance, self.action, self.task, self._penalty_scale)
        terminated = (distance <= self.task.success_radius) & self.task.terminate_on_success
        return reward, terminated, self.elapsed >= self.task.max_episode_steps

    def _final(self, info: dict[str, torch.Tensor], done: torch.Tensor
               ) -> dict[str, Any]:
        return {"final_obs": self._observation(), "_final_obs": done,
                "final_info": {key: info[key] for key in INFO_KEYS}, "_final_info": done}

    def compute_reward(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor,
                       info: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The reward ``(...)`` of transitions (HER relabelling), on the goals' device.

        ``achieved_goal``, ``desired_goal``: ``(..., 3)`` m, world frame (broadcast);
        ``info["action"]``: ``(..., n)`` the actions as applied (unused if sparse). Equals
        :func:`envs.task.compute_reward`; checks shapes only (a value check would sync).
        """
        for name, g in (("achieved_goal", achieved_goal), ("desired_goal", desired_goal)):
            if not isinstance(g, torch.Tensor) or g.ndim == 0 or g.shape[-1] != GOAL_DIM:
                raise ValueError(f"{name} must be a (..., 3) tensor (m, world frame); got "
                                 f"{getattr(g, 'shape', type(g).__name__)}")
        distance = goal_distance(achieved_goal, desired_goal)
        if self.task.reward_type == "sparse":
            return reach_reward(distance, None, self.task, None)
        action = info.get(ACTION_KEY) if isinstance(info, Mapping) else None
        n = self.task.n_joints
        if not isinstance(action, torch.Tensor) or action.ndim == 0 or action.shape[-1] != n:
            raise ValueError(f"the dense reward needs info[{ACTION_KEY!r}], a (..., {n}) tensor "
                             f"of the actions as applied; got "
                             f"{getattr(action, 'shape', type(action).__name__)}")
        scale = self._penalty_scale.to(device=action.device, dtype=action.dtype)
        return reach_reward(distance, action, self.task, scale)

    def compute_terminated(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor,
                           info: Mapping[str, torch.Tensor] | None = None) -> torch.Tensor:
        """Whether transitions ``(...)`` end their episode: a success (``distance <=
        success_radius``) when ``terminate_on_success``, as
        :meth:`envs.UR5ReachEnv.compute_terminated`; goals ``(..., 3)`` m, world frame."""
        success = goal_distance(achieved_goal, desired_goal) <= self.task.success_radius
        return success & self.task.terminate_on_success

    @property
    def unwrapped(self) -> TorchReach:
        """Itself (the Gymnasium convention, so ``gymnasium.make_vec`` can set ``spec``)."""
        return self

    def close(self) -> None:
        """Nothing to release (the tensors go with the object)."""

    # ------------------------------------------------------------------ internals
    def _reset_where(self, mask: torch.Tensor) -> None:
        """Start new episodes where ``mask``: arm at rest at the start pose, next goal."""
        self.dynamics.reset_where(mask, self._start_q)
        self.goals.draw(mask, self.goal)
        self.elapsed.masked_fill_(mask, 0)
        self.action.masked_fill_(mask.unsqueeze(-1), 0.0)

    def _distance(self) -> torch.Tensor:
        return goal_distance(self.dynamics.tool, self.goal)

    def _observation(self) -> dict[str, torch.Tensor]:
        d, n = self.dynamics, self.task.n_joints
        return {"observation": torch.cat([d.q[:, :n], d.v[:, :n], d.acceleration[:, :n]], -1),
                "achieved_goal": d.tool_positions(), "desired_goal": self.goal.clone()}

    def _info(self) -> dict[str, torch.Tensor]:
        d, distance = self.dynamics, self._distance()
        values = (self.action.clone(), distance, distance <= self.task.success_radius,
                  d.contact.clone(), d.limit_stop.clone(), d.clearance())
        info = dict(zip(INFO_KEYS, values, strict=True))
        info.update({f"_{key}": self._all for key in INFO_KEYS})
        return info
