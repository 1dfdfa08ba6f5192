"""Which goals is reaching worth it for? The optimality diagnostic of issue 13 (item 2).

    python -m analysis.optimality --regions unconstrained zheight closebox farbox --joints 3 \
        --goals 500 --readings ours actor_penalty --out DIR
    python -m analysis.optimality --settings farbox:6 unconstrained:2 --grid 16 --out DIR
    python -m analysis.optimality --settings zheight:3 --goals 100 --out runs/optimality

Per goal of a task, constant commands (the goal's analytic IK branches, ``stay`` at the start
pose, ``zero``) are held for a whole episode in the env's own dynamics, reward and termination. A
goal is **worth reaching** when the best discounted return (``sum_t gamma^t r_t``) among the
candidates that reach it exceeds the best of stay and zero among those that do not: an estimate
for comparing regions and readings, not a bound (results/optimality/README.md, "What is
computed"). :func:`simulate` runs once per dynamics; :func:`evaluate` scores it under any reward
reading.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import functools
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from analysis.outputs import (
    add_force,
    check_files,
    pyplot,
    save_figure,
    usage_errors,
    write_csv,
    write_errors,
)
from analysis.readings import READINGS as STUDY_READINGS
from analysis.readings import missing_fields, task_fields
from analysis.sweep import parse_setting
from ddpg_her.config import VALID, Parser
from ddpg_her.runfolder import RunFolderError
from ddpg_her.units import task_option
from ur5kin.checks import COUNT, SEED, Kind, is_integer

DEFAULT_GAMMA = 0.98
"""The discount of the paper's Table I (and of :class:`ddpg_her.config.AgentConfig`)."""

CONFIDENCE = 0.95
"""Level of the binomial (Wilson score) interval of the shares."""

READINGS: dict[str, dict[str, Any]] = {
    name: task_fields(reading.args) for name, reading in STUDY_READINGS.items()
    if not reading.args or task_fields(reading.args)}
"""The sensitivity study's readings (:data:`analysis.readings.READINGS`) that change the task,
as TaskSpec fields over the defaults: ``ours`` (rad^2 action penalty, stopping contact),
``actor_penalty`` (eq. 2's ``|a|^2`` in the actor's units ``(a / pi)^2``), ``compliant`` (the
compliant ground contact). Readings of the agent alone (exploration, warm-up) leave the
diagnostic unchanged and are left out."""

EVALUATION_FIELDS = ("reward_type", "distance_weight", "action_weight", "action_penalty_unit",
                     "success_reward", "success_radius", "terminate_on_success")
"""TaskSpec fields that change the reward or the episode end but not the motion: rollouts of two
tasks that differ only here are the same, and one :class:`Simulation` serves both."""

DUPLICATE_TOL = 1e-6
"""Commands closer than this (rad, every joint, after wrapping) count as one IK branch."""

FIXED_JOINT_TOL = 1e-6
"""An IK solution is a branch of an n-joint task only if joints n+1..6 match the start angles
to this (rad, wrapped)."""

CHUNK = 2048
"""Most copies rolled out at once (memory: the history of a step is (21, B, 18) floats)."""

CSV_COLUMNS = ("region", "joints", "reading", "goals", "gamma", "share_worth", "ci_low", "ci_high",
               "share_reachable", "share_worth_if_reachable", "mean_gap", "mean_best_reach_return",
               "mean_stay_return", "mean_zero_return", "mean_branches", "grid_per_joint",
               "share_worth_grid", "agreement_grid", "seed", "seconds", "action_penalty_unit",
               "action_weight", "reward_type", "contact_model", "held_joints", "start_q")
"""Columns of the CSV: one row per region x joints x reading. Shares in [0, 1] with the
:data:`CONFIDENCE` Wilson interval on ``share_worth``; returns are discounted returns (reward
units); ``mean_gap`` is the mean over goals with both of (best reaching return - best non-reaching
stay/zero return). The ``*_grid`` columns hold the :func:`brute_force` check (the share it finds
worth reaching, and the share of goals on which both decisions agree), empty when it was not run."""


# ---------------------------------------------------------------------- candidates
def ik_branches(task: Any, goals: np.ndarray, q_sampled: np.ndarray) -> np.ndarray:
    """Analytic IK branches of each goal for the task's controlled joints.

    Parameters
    ----------
    task : envs.TaskSpec
    goals : (N, 3) float, m, world frame
        Goals (base at (0, 0, ``task.base_height``)).
    q_sampled : (N, 6) float, rad
        The configuration each goal was sampled from (joints n+1..6 at the start angles).

    Returns
    -------
    commands : (N, K, n) float, rad, in [-pi, pi]
        Distinct configurations of joints 1..n that put tool0 at the goal with joints n+1..6 at
        the start angles; rows past a goal's branch count hold NaN. Sources: the sampled
        configuration; :func:`ur5kin.ik_position` with joints 4-6 at the start (up to 2 pans x 2
        elbows; for n = 2 only those whose elbow equals the start's) and, for n >= 4, at the
        sampled configuration's angles; for n = 6 also every :func:`ur5kin.ik` solution of the
        sampled tool pose (up to 8).
    """
    import ur5kin

    goals = np.asarray(goals, dtype=float)
    q_sampled = np.asarray(q_sampled, dtype=float)
    if goals.ndim != 2 or goals.shape[1] != 3 or q_sampled.shape != (len(goals), 6):
        raise ValueError(f"goals must be (N, 3) m and q_sampled (N, 6) rad; got shapes "
                         f"{goals.shape} and {q_sampled.shape}")
    n, start = task.n_joints, np.asarray(task.start_q)
    base = goals - np.array([0.0, 0.0, task.base_height])
    # joints 4-6 at the start's angles; for n >= 4 also at the sampled configuration's
    wrists = [np.broadcast_to(start[3:], (len(goals), 3))] + ([q_sampled[:, 3:]] if n > 3 else [])
    position_ik = [ur5kin.ik_position(base, w) for w in wrists]
    rows: list[list[np.ndarray]] = []
    for i in range(len(goals)):
        found = [q_sampled[i]] + [pos_q[i, k] for pos_q, pos_ok in position_ik
                                  for k in np.flatnonzero(pos_ok[i])]
        if n == 6:
            found += list(ur5kin.ik(ur5kin.fk_pose(q_sampled[i])))
        unique: list[np.ndarray] = []
        for q in found:
            q = ur5kin.wrap(np.asarray(q, dtype=float))
            if np.abs(ur5kin.wrap(q[n:] - start[n:])).max(initial=0.0) > FIXED_JOINT_TOL:
                continue  # moves a joint the task holds
            if not any(np.abs(ur5kin.wrap(q[:n] - u)).max() < DUPLICATE_TOL for u in unique):
                unique.append(q[:n])
        rows.append(unique)
    width = max(len(r) for r in rows) if rows else 1
    out = np.full((len(goals), width, n), np.nan)
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
    return out


# ---------------------------------------------------------------------- rollouts
def rollout(task: Any, commands: np.ndarray, goals: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Hold constant commands for a whole episode in the env's own dynamics.

    Parameters
    ----------
    task : envs.TaskSpec
        Position control (constant commands of other modes are not policies that reach).
    commands : (B, n) float, rad
        One command per copy, clipped by the env to its action box.
    goals : (B, 3) float, m, world frame, optional
        Passed to the env's reset; they do not change the motion.

    Returns
    -------
    achieved : (B, T, 3) float, m, world frame
        tool0 after each of the ``T = task.max_episode_steps`` steps.
    actions : (B, n) float, rad
        The commands as the env applied them (after clipping).
    """
    from envs import BatchedReach

    commands = np.asarray(commands, dtype=float)
    B, T = len(commands), task.max_episode_steps
    achieved = np.empty((B, T, 3))
    actions = np.empty_like(commands)
    for lo in range(0, B, CHUNK):
        part = commands[lo : lo + CHUNK]
        env = BatchedReach(len(part), task, dynamics="pinocchio", autoreset_mode="disabled")
        part_goals = (np.zeros((len(part), 3)) if goals is None
                      else np.asarray(goals, dtype=float)[lo : lo + CHUNK])
        env.reset(options={"goal": part_goals})
        for t in range(T):
            obs, *_, info = env.step(part)
            achieved[lo : lo + len(part), t] = obs["achieved_goal"]
        actions[lo : lo + len(part)] = info["action"]
    return achieved, actions


def discounted_returns(task: Any, achieved: np.ndarray, goals: np.ndarray,
                       actions: np.ndarray, gamma: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discounted return and success of episodes, with the env's reward and termination.

    Parameters
    ----------
    task : envs.TaskSpec
    achieved : (..., T, 3) float, m, world frame
        tool0 after each step.
    goals : (..., 3) float, m, world frame
    actions : (..., n) float, rad
        The constant applied command (the dense reward's ``a``).
    gamma : float
        Discount in [0, 1].

    Returns
    -------
    returns : (...) float
        ``sum_{t < end} gamma^t r_t``, ``r_t`` the reward of step t + 1 (the env's,
        :meth:`envs.task.TaskRules.reward`), ``end`` the first step after which the episode is
        terminated (success with ``terminate_on_success``) or T.
    reached : (...) bool
        Whether the episode had a success before it ended.
    steps : (...) int
        The episode's length ``end`` (steps, 1..T).
    """
    from envs.task import TaskRules

    rules = TaskRules(task)
    distance = rules.distance(achieved, np.asarray(goals)[..., None, :])  # (..., T)
    reward = rules.reward(distance, np.asarray(actions)[..., None, :])
    success = distance <= task.success_radius
    T = distance.shape[-1]
    if task.terminate_on_success:
        # steps up to and including the first success count; later ones never happen
        ended_before = np.cumsum(success, axis=-1) - success > 0
        reward = np.where(ended_before, 0.0, reward)
    returns = reward @ gamma ** np.arange(T)
    reached = success.any(axis=-1)
    steps = np.where(reached & task.terminate_on_success, np.argmax(success, axis=-1) + 1, T)
    return returns, reached, steps


# ---------------------------------------------------------------------- the study
@dataclass(frozen=True, eq=False)
class Simulation:
    """Rollouts of every candidate of every goal: reusable for any reward reading.

    Attributes
    ----------
    task : envs.TaskSpec
        The task simulated (its :data:`EVALUATION_FIELDS` do not matter).
    seed : int
        Goal i is the env's goal after ``reset(seed=seed + i)``.
    goals : (N, 3) float, m, world frame
    branches : (N, K, n) float, rad
        IK branch commands (NaN-padded, :func:`ik_branches`).
    branch_achieved : (N, K, T, 3) float, m, world frame
        tool0 under each branch command (NaN where no branch).
    branch_actions : (N, K, n) float, rad
    hold_commands : (2, n) float, rad
        The stay and zero commands.
    hold_achieved : (2, T, 3) float, m, world frame
        tool0 under stay and zero (goal-independent motions, simulated once).
    seconds : float
        Wall time of the rollouts.
    """

    task: Any
    seed: int
    goals: np.ndarray
    branches: np.ndarray
    branch_achieved: np.ndarray
    branch_actions: np.ndarray
    hold_commands: np.ndarray
    hold_achieved: np.ndarray
    seconds: float


def env_goals(task: Any, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The goals ``BatchedReach(count, task).reset(seed=seed)`` draws, and their configurations.

    Returns
    -------
    goals : (count, 3) float, m, world frame
    q : (count, 6) float, rad
        The sampled configuration of each goal.
    """
    from gymnasium.utils import seeding

    from envs.task import TaskRules

    sampler = TaskRules(task).sampler
    batches = [sampler.sample(1, seeding.np_random(seed + i)[0]) for i in range(count)]
    return (np.concatenate([b.goals for b in batches]).reshape(-1, 3),
            np.concatenate([b.q for b in batches]).reshape(-1, 6))


def _check_task(task: Any) -> Any:
    from envs.spec import TaskSpec

    if not isinstance(task, TaskSpec):
        raise ValueError(f"task must be an envs.TaskSpec; got {type(task).__name__}")
    if task.control_mode != "position":
        raise ValueError(f"the diagnostic holds constant joint-angle commands, so it needs "
                         f"control_mode='position'; got {task.control_mode!r}")
    return task


def simulate(task: Any, goals: int = 500, seed: int = 0) -> Simulation:
    """Roll out every candidate command of ``goals`` goals of ``task``.

    Parameters
    ----------
    task : envs.TaskSpec
        Position control.
    goals : int
        Number of goals N >= 1.
    seed : int
        Goal i is the one the env draws after ``reset(seed=seed + i)``.
    """
    _check_task(task)
    goals, seed = COUNT("goals", goals), SEED("seed", seed)
    began = time.perf_counter()
    g, q = env_goals(task, goals, seed)
    branches = ik_branches(task, g, q)
    N, K, n = branches.shape
    T = task.max_episode_steps
    have = ~np.isnan(branches[..., 0])
    achieved = np.full((N, K, T, 3), np.nan)
    actions = np.full((N, K, n), np.nan)
    goal_of = np.broadcast_to(g[:, None, :], (N, K, 3))
    achieved[have], actions[have] = rollout(task, branches[have], goal_of[have])
    hold = np.stack([np.asarray(task.start_q[:n]), np.zeros(n)])
    hold_achieved, hold_actions = rollout(task, hold)
    return Simulation(task, int(seed), g, branches, achieved, actions, hold_actions,
                      hold_achieved, time.perf_counter() - began)


def _dynamics_key(task: Any) -> Any:
    defaults = {f.name: f.default for f in dataclasses.fields(task)}
    return task.replace(**{name: defaults[name] for name in EVALUATION_FIELDS})


@dataclass(frozen=True, eq=False)
class OptimalityResult:
    """The diagnostic for one task and discount (see the module docstring).

    Attributes
    ----------
    task : envs.TaskSpec
    gamma : float
    seed : int
    goals : (N, 3) float, m, world frame
    branch_returns : (N, K) float
        Discounted return of each IK branch (NaN where the goal has fewer branches).
    branch_reached : (N, K) bool
    branch_steps : (N, K) int
        Episode length (steps) of each branch: its first success, or T; 0 where no branch.
    stay_return, zero_return : (N,) float
        Discounted returns of commanding the start pose and the zero pose.
    stay_reached, zero_reached : (N,) bool
    """

    task: Any
    gamma: float
    seed: int
    goals: np.ndarray
    branch_returns: np.ndarray
    branch_reached: np.ndarray
    branch_steps: np.ndarray
    stay_return: np.ndarray
    zero_return: np.ndarray
    stay_reached: np.ndarray
    zero_reached: np.ndarray
    seconds: float = math.nan

    @property
    def n_goals(self) -> int:
        return len(self.goals)

    @property
    def best_reach_return(self) -> np.ndarray:
        """(N,) best return among the candidates that reach the goal; -inf if none does."""
        cands = np.concatenate([np.where(self.branch_reached, self.branch_returns, -np.inf),
                                np.where(self.stay_reached, self.stay_return, -np.inf)[:, None],
                                np.where(self.zero_reached, self.zero_return, -np.inf)[:, None]],
                               axis=1)
        return cands.max(axis=1)

    @property
    def best_hold_return(self) -> np.ndarray:
        """(N,) best return of stay and zero among those that do not reach; -inf if both do."""
        return np.maximum(np.where(self.stay_reached, -np.inf, self.stay_return),
                          np.where(self.zero_reached, -np.inf, self.zero_return))

    @property
    def reachable(self) -> np.ndarray:
        """(N,) bool: some candidate (an IK branch, stay or zero) reaches the goal."""
        return self.branch_reached.any(axis=1) | self.stay_reached | self.zero_reached

    @property
    def worth(self) -> np.ndarray:
        """(N,) bool: the goal is reachable and reaching it beats holding (module docstring)."""
        return self.reachable & (self.best_reach_return > self.best_hold_return)

    @property
    def share_worth(self) -> float:
        return float(self.worth.mean())

    @functools.cached_property
    def share_worth_ci(self) -> tuple[float, float]:
        """Wilson score interval (level :data:`CONFIDENCE`) of :attr:`share_worth`."""
        from scipy.stats import binomtest

        ci = binomtest(int(self.worth.sum()), self.n_goals).proportion_ci(
            confidence_level=CONFIDENCE, method="wilson")
        return float(ci.low), float(ci.high)

    @property
    def share_reachable(self) -> float:
        return float(self.reachable.mean())

    @property
    def mean_gap(self) -> float:
        """Mean of best reach - best hold return, over goals where both exist (NaN if none)."""
        both = np.isfinite(self.best_reach_return) & np.isfinite(self.best_hold_return)
        gap = self.best_reach_return[both] - self.best_hold_return[both]
        return float(gap.mean()) if gap.size else math.nan

    def row(self, reading: str = "") -> dict[str, Any]:
        """One CSV row (:data:`CSV_COLUMNS`)."""
        low, high = self.share_worth_ci
        reach = self.reachable
        best = self.best_reach_return
        task = self.task
        return {
            "region": task.region, "joints": task.n_joints, "reading": reading,
            "goals": self.n_goals, "gamma": self.gamma,
            "share_worth": round(self.share_worth, 4), "ci_low": round(low, 4),
            "ci_high": round(high, 4), "share_reachable": round(self.share_reachable, 4),
            "share_worth_if_reachable": (round(float(self.worth[reach].mean()), 4)
                                         if reach.any() else math.nan),
            "mean_gap": round(self.mean_gap, 3),
            "mean_best_reach_return": (round(float(best[reach].mean()), 3)
                                       if reach.any() else math.nan),
            "mean_stay_return": round(float(self.stay_return.mean()), 3),
            "mean_zero_return": round(float(self.zero_return.mean()), 3),
            "mean_branches": round(float(np.isfinite(self.branch_returns).sum(1).mean()), 3),
            "seed": self.seed, "seconds": round(self.seconds, 1),
            "action_penalty_unit": task.action_penalty_unit,
            "action_weight": task.action_weight, "reward_type": task.reward_type,
            "contact_model": getattr(task, "contact_model", "stop"),
            "held_joints": task.held_joints,
            "start_q": " ".join(f"{x:.6g}" for x in task.start_q),
        }


def evaluate(simulation: Simulation, task: Any | None = None,
             gamma: float = DEFAULT_GAMMA) -> OptimalityResult:
    """Score a :class:`Simulation` under ``task``'s reward (default: the simulated task's).

    Raises
    ------
    ValueError
        When ``task`` differs from the simulated one in a field that changes the motion (only
        :data:`EVALUATION_FIELDS` may differ), or ``gamma`` is outside [0, 1].
    """
    task = simulation.task if task is None else _check_task(task)
    if _dynamics_key(task) != _dynamics_key(simulation.task):
        raise ValueError("the task differs from the simulated one in a field that changes the "
                         f"motion (only {list(EVALUATION_FIELDS)} may differ); simulate it anew")
    gamma = VALID["gamma"]("gamma", gamma)
    sim = simulation
    N, K = sim.branches.shape[:2]
    goal_of = np.broadcast_to(sim.goals[:, None, :], (N, K, 3))
    br, breach, bsteps = discounted_returns(task, sim.branch_achieved, goal_of, sim.branch_actions,
                                    float(gamma))
    have = ~np.isnan(sim.branches[..., 0])
    br = np.where(have, br, np.nan)
    breach &= have
    hold_goal = np.broadcast_to(sim.goals[:, None, :], (N, 2, 3))
    hold_ach = np.broadcast_to(sim.hold_achieved[None], (N, *sim.hold_achieved.shape))
    hold_act = np.broadcast_to(sim.hold_commands[None], (N, *sim.hold_commands.shape))
    hr, hreach, _ = discounted_returns(task, hold_ach, hold_goal, hold_act, float(gamma))
    return OptimalityResult(task, float(gamma), sim.seed, sim.goals, br, breach,
                            np.where(have, bsteps, 0), hr[:, 0], hr[:, 1], hreach[:, 0],
                            hreach[:, 1], sim.seconds)


def worth_reaching(task: Any, goals: int = 500, gamma: float = DEFAULT_GAMMA,
                   seed: int = 0) -> OptimalityResult:
    """The optimality diagnostic of ``task`` (an envs.TaskSpec, position control; its reward
    fields are the reading scored): :func:`evaluate`, with discount ``gamma`` in [0, 1], of
    :func:`simulate` of ``goals`` goals from ``seed``."""
    return evaluate(simulate(task, goals, seed), task, gamma)


BRUTE_MAX_COMMANDS = 20_000
"""Most grid commands :func:`brute_force` rolls out (``per_joint ** n``)."""


@dataclass(frozen=True, eq=False)
class BruteForce:
    """The diagnostic's decision against every constant command of a joint-space grid.

    Attributes
    ----------
    commands : (M, n) float, rad
        The grid: ``per_joint`` angles in [-pi, pi] per controlled joint.
    best_reach_return : (N,) float
        Best return among the grid commands and the diagnostic's candidates that reach the goal
        (-inf if none does).
    best_hold_return : (N,) float
        Best return among the grid commands, stay and zero that do not reach it.
    worth : (N,) bool
        ``best_reach_return > best_hold_return``: the best constant command of all reaches.
    """

    commands: np.ndarray
    best_reach_return: np.ndarray
    best_hold_return: np.ndarray
    worth: np.ndarray


def _motion_key(task: Any) -> Any:
    """``task`` with every field that cannot change a constant command's motion at defaults
    (the reward fields and the region; the start pose stays)."""
    return _dynamics_key(task).replace(region="unconstrained", start_q=task.start_q)


@functools.lru_cache(maxsize=4)
def _grid_rollout(task: Any, per_joint: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid of :func:`brute_force` and its rollout (cached: readings and regions share it)."""
    n = task.n_joints
    axis = np.linspace(-np.pi, np.pi, per_joint)
    commands = np.stack(np.meshgrid(*[axis] * n, indexing="ij"), axis=-1).reshape(-1, n)
    return (commands, *rollout(task, commands))


def brute_force(simulation: Simulation, task: Any | None = None,
                gamma: float = DEFAULT_GAMMA, per_joint: int = 16) -> BruteForce:
    """Check the diagnostic against a brute-force search over constant commands.

    Every command of a ``per_joint ** n`` grid over [-pi, pi]^n is rolled out once (the motion
    does not depend on the goal) and scored against every goal of ``simulation``; with the
    diagnostic's own candidates added, the best reaching and the best non-reaching constant
    command of each goal decide. The grid's non-reaching commands include poses that hover near
    the goal more cheaply than stay or zero, so this decision is the stricter one.

    Raises
    ------
    ValueError
        When the grid would exceed :data:`BRUTE_MAX_COMMANDS` commands.
    """
    task = simulation.task if task is None else task
    result = evaluate(simulation, task, gamma)
    n = task.n_joints
    if not isinstance(per_joint, int | np.integer) or per_joint < 2 \
            or per_joint ** n > BRUTE_MAX_COMMANDS:
        raise ValueError(f"per_joint must be an integer >= 2 with per_joint ** n_joints <= "
                         f"{BRUTE_MAX_COMMANDS}; got per_joint={per_joint!r}, n_joints={n}")
    commands, achieved, actions = _grid_rollout(_motion_key(task), int(per_joint))
    reach_best, hold_best = result.best_reach_return.copy(), result.best_hold_return.copy()
    for i in range(len(simulation.goals)):
        ret, reached, _ = discounted_returns(task, achieved, simulation.goals[i], actions,
                                             float(gamma))
        if reached.any():
            reach_best[i] = max(reach_best[i], ret[reached].max())
        if (~reached).any():
            hold_best[i] = max(hold_best[i], ret[~reached].max())
    worth = np.isfinite(reach_best) & (reach_best > hold_best)
    return BruteForce(commands, reach_best, hold_best, worth)


# ---------------------------------------------------------------------- readings, CLI
def reading_fields(name: str) -> dict[str, Any]:
    """The TaskSpec fields of a named reading; ``ValueError`` for an unknown name."""
    if name not in READINGS:
        raise ValueError(f"unknown reading {name!r}; the readings are {list(READINGS)}")
    return dict(READINGS[name])


def check_overrides(overrides: Sequence[tuple[str, Any]], readings: Sequence[str]
                    ) -> dict[str, Any]:
    """The ``--task KEY=VALUE`` pairs as the TaskSpec fields they set, checked before any
    computing as ``ddpg_her.train`` checks its own: every key a TaskSpec field, none the study
    sets itself (region and n_joints, from --regions, --joints or --settings; a field one of
    ``readings`` sets, which would win over it unseen), none given twice with two values, and
    the values ones TaskSpec accepts.

    Raises
    ------
    ValueError
        Naming the key and what was expected.
    """
    from ddpg_her import units
    from envs.spec import TaskSpec

    known = [f.name for f in dataclasses.fields(TaskSpec)]
    for key, _ in overrides:
        if key not in known:
            raise ValueError(f"--task {key}: TaskSpec has no field {key!r}; its fields are "
                             f"{', '.join(known)}")
        if key in ("region", "n_joints"):
            raise ValueError(f"--task {key}: the study sets it for every setting (--regions, "
                             "--joints or --settings)")
        owners = [name for name in readings if key in READINGS.get(name, {})]
        if owners:
            raise ValueError(f"--task {key}: the reading(s) {', '.join(owners)} set it "
                             "themselves; drop it or choose other --readings")
    fields = units.task_fields("", None, overrides)  # refuses a key given two values
    del fields["region"], fields["n_joints"]
    try:
        TaskSpec(**fields)
    except (TypeError, ValueError) as err:
        raise ValueError(f"--task: {err}") from None
    return fields


def study(settings: Sequence[tuple[str, int]], readings: Sequence[str],
          overrides: Mapping[str, Any], goals: int, gamma: float, seed: int,
          grid: int = 0, progress: bool = True) -> tuple[list[dict[str, Any]], list[str]]:
    """Rows (:data:`CSV_COLUMNS`) for every (region, joints) setting x reading, and the
    readings skipped.

    Readings whose fields TaskSpec lacks are skipped (named in the second list). Settings that
    share their dynamics share one :class:`Simulation`. ``grid`` > 0 adds the
    :func:`brute_force` check with that many angles per joint, where the grid has at most
    :data:`BRUTE_MAX_COMMANDS` commands.
    """
    from tqdm import tqdm

    from envs.spec import TaskSpec

    missing = [(name, sorted(missing_fields(reading_fields(name)))) for name in readings]
    skipped = [f"reading {name!r} skipped: TaskSpec has no field(s) {m} in this version"
               for name, m in missing if m]
    usable = [name for name, m in missing if not m]
    rows = []
    units = [(r, j, name) for r, j in settings for name in usable]
    cache: dict[Any, Simulation] = {}
    with tqdm(total=len(units), desc="optimality", unit="setting", file=sys.stderr,
              disable=not progress) as bar:
        for region, n, name in units:
            task = TaskSpec(region=region, n_joints=n, **{**overrides, **reading_fields(name)})
            key = _dynamics_key(task)
            if key not in cache:
                bar.set_postfix_str(f"{region} j{n} {name}: rollouts")
                cache.clear()  # one simulation at a time: each holds (N, K, T, 3) paths
                cache[key] = simulate(task, goals, seed)
            result = evaluate(cache[key], task, gamma)
            row = result.row(name)
            row.update(grid_per_joint="", share_worth_grid="", agreement_grid="")
            if grid and grid ** n <= BRUTE_MAX_COMMANDS:
                bar.set_postfix_str(f"{region} j{n} {name}: grid")
                check = brute_force(cache[key], task, gamma, grid)
                row.update(grid_per_joint=grid,
                           share_worth_grid=round(float(check.worth.mean()), 4),
                           agreement_grid=round(float((check.worth == result.worth).mean()), 4))
            rows.append(row)
            bar.update(1)
    return rows, skipped


def _column(by_setting: Mapping[tuple[str, int], Mapping[str, Any]],
            settings: Sequence[tuple[str, int]], key: str, optional: bool = False) -> np.ndarray:
    """One reading's ``key`` per setting: NaN where it has no row, or (``optional``, as the
    grid check that was not run) an empty cell; any other value must be a number."""
    return np.array([np.nan if s not in by_setting
                     or (optional and by_setting[s].get(key) in ("", None))
                     else float(by_setting[s][key]) for s in settings])


def plot(rows: Sequence[Mapping[str, Any]], ax: Any = None, out: Path | None = None) -> Any:
    """Bar chart of the share worth reaching per setting, one bar per reading, with CIs.

    Parameters
    ----------
    rows : rows of :data:`CSV_COLUMNS`; share_reachable NaN draws no reachable marks
    ax : matplotlib Axes, optional
        Draw into it (e.g. beside learning curves); else a new figure.
    out : Path, optional
        Save the figure there.

    Returns
    -------
    The Axes drawn into.
    """
    settings = list(dict.fromkeys((r["region"], int(r["joints"])) for r in rows))
    readings = list(dict.fromkeys(r["reading"] for r in rows))
    if ax is None:
        fig_width = max(5.0, 1.3 * len(settings) * max(1, len(readings)) / 2 + 2.0)
        _, ax = pyplot().subplots(figsize=(fig_width, 3.8))
    width = 0.8 / max(1, len(readings))
    x = np.arange(len(settings))
    for k, name in enumerate(readings):
        by_setting = {(r["region"], int(r["joints"])): r for r in rows if r["reading"] == name}
        share, low, high, reach = (_column(by_setting, settings, key) for key in
                                   ("share_worth", "ci_low", "ci_high", "share_reachable"))
        grid = _column(by_setting, settings, "share_worth_grid", optional=True)
        pos = x - 0.4 + width * (k + 0.5)
        ax.bar(pos, 100 * share, width, color=f"C{k}", label=f"{name}: worth reaching")
        ax.errorbar(pos, 100 * share, yerr=100 * np.abs(np.stack([share - low, high - share])),
                    fmt="none", ecolor="k", lw=0.8, capsize=2)
        if np.isfinite(reach).any():  # NaN: not computed (analysis.sensitivity's shares)
            ax.scatter(pos, 100 * reach, marker="_", s=120, color="k", zorder=3,
                       label="reachable by a constant command" if k == 0 else None)
        if np.isfinite(grid).any():
            ax.scatter(pos, 100 * grid, marker="x", s=25, color="0.3", zorder=3,
                       label="grid of constant commands (check)" if k == 0 else None)
    ax.set_xticks(x, [f"{r}\n{j} joints" for r, j in settings], fontsize=8)
    ax.set_ylim(0, 105)
    ax.set_ylabel("goals (%)")
    ax.set_title("Goals worth reaching under a constant command (95 % Wilson CI)", fontsize=9)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    if out is not None:
        save_figure(ax.figure, out, dpi=120, bbox_inches="tight")
    return ax


def _run_label(run: Any) -> str:
    """``region jN`` plus the run's reward reading where it is not the default one."""
    task = run.spec.get("task", {})
    extra = []
    if task.get("action_penalty_unit", "command") != "command":
        extra.append(f"penalty {task['action_penalty_unit']}")
    if float(task.get("action_weight", 1.0)) != 1.0:
        extra.append(f"w={float(task['action_weight']):g}")
    if task.get("contact_model", "stop") != "stop":
        extra.append(str(task["contact_model"]))
    return f"{run.region} j{run.joints}" + (f" ({', '.join(extra)})" if extra else "")


def plot_beside_curves(rows: Sequence[Mapping[str, Any]], roots: Sequence[Path],
                       out: Path) -> None:
    """Learning curves of the runs below ``roots`` (left) beside the shares (right).

    Every run folder (``spec.json`` + ``eval.csv``, :mod:`analysis.runs`) of a setting in
    ``rows`` is drawn: the mean over its seeds of the test successes per 100 goals, one line per
    (setting, reading of the run), coloured by setting as the bars' x labels order them.
    """
    from analysis.runs import aligned_successes, find_runs

    settings = list(dict.fromkeys((r["region"], int(r["joints"])) for r in rows))
    groups: dict[str, list[Any]] = {}
    for run in find_runs(roots):
        if run.setting in settings and len(run.episode):
            # one line per experiment: seeds of one folder share their evaluation episodes
            groups.setdefault(f"{_run_label(run)} [{run.path.parent.name}]", []).append(run)
    fig, (left, right) = pyplot().subplots(1, 2, figsize=(13.0, 4.2),
                                           gridspec_kw={"width_ratios": [1.0, 1.2]})
    for label, runs in sorted(groups.items()):
        episode, percent = aligned_successes(runs)
        color = f"C{settings.index(runs[0].setting) % 10}"
        style = "-" if "(" not in label.split("[")[0] else "--"
        left.plot(episode, percent.mean(axis=0), style, color=color, lw=1.4,
                  label=f"{label}, {len(runs)} seeds")
    left.set_xlabel("training episodes")
    left.set_ylabel("test successes per 100 goals (mean over seeds)")
    left.set_ylim(0, 100)
    left.set_title("Learning curves (committed runs)", fontsize=9)
    if groups:
        left.legend(fontsize=6.5, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    plot(rows, ax=right)
    for k, tick in enumerate(right.get_xticklabels()):
        tick.set_color(f"C{k % 10}")
    fig.tight_layout()
    save_figure(fig, out, dpi=120, bbox_inches="tight")


def read_csvs(paths: Sequence[Path]) -> list[dict[str, str]]:
    """The rows of optimality.csv files written by earlier runs (``--from-csv``).

    Raises
    ------
    ValueError
        Naming the file, when one cannot be read, lacks a column of :data:`CSV_COLUMNS` (it is
        not an optimality.csv) or holds no row: joining it would write empty or wrong outputs.
    """
    rows: list[dict[str, str]] = []
    for path in paths:
        try:
            with open(path, newline="") as f:
                reader = csv.DictReader(f)
                found = list(reader)
                header = reader.fieldnames or []
        except (OSError, UnicodeDecodeError, csv.Error) as err:
            raise ValueError(f"--from-csv {path}: cannot be read ({err})") from None
        lacking = [c for c in CSV_COLUMNS if c not in header]
        if lacking:
            raise ValueError(f"--from-csv {path}: not an optimality.csv (no column "
                             f"{', '.join(lacking[:3])}{' ...' if len(lacking) > 3 else ''})")
        if not found:
            raise ValueError(f"--from-csv {path}: holds no row")
        rows += found
    return rows


GRID = Kind("0 (off) or an integer >= 2 (angles per joint)",
            lambda v: is_integer(v) and (v == 0 or v >= 2), int, int)
"""The --grid count."""


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(
        prog="python -m analysis.optimality",
        description="Share of goals for which reaching them under a constant joint command "
                    "(an analytic IK branch) earns a higher discounted return than holding the "
                    "start pose or commanding the zero pose, in the env's own dynamics and "
                    "reward. Constant commands bound a learner's return from below on both "
                    "sides, so the share is an estimate for comparing regions and readings. "
                    "Writes DIR/optimality.csv and DIR/optimality.png.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--regions", nargs="+", default=["unconstrained", "zheight", "closebox",
                                                          "farbox"],
                        help="goal regions (names or region strings as TaskSpec.region takes)")
    parser.add_argument("--joints", nargs="+", type=int, default=[3],
                        help="controlled joint counts n (2-6), each crossed with every region")
    parser.add_argument("--settings", nargs="+", type=parse_setting, default=None,
                        metavar="REGION:N",
                        help="explicit (region, joints) settings, e.g. farbox:6 "
                             "unconstrained:2; replaces the --regions x --joints product")
    parser.add_argument("--readings", nargs="+", default=["ours", "actor_penalty"],
                        choices=list(READINGS),
                        help="named readings (TaskSpec fields over the defaults): "
                             + "; ".join(f"{k}={v}" for k, v in READINGS.items())
                             + ". A reading whose field this TaskSpec lacks is skipped")
    parser.add_argument("--task", type=task_option, action="append", default=[],
                        metavar="KEY=VALUE",
                        help="override a TaskSpec field for every setting (VALUE read as JSON, "
                             "else as a string), e.g. --task action_weight=0.5; a reading's "
                             "own fields win over these")
    parser.add_argument("--goals", type=COUNT.read, default=500,
                        help="goals per setting (count >= 1)")
    parser.add_argument("--gamma", type=VALID["gamma"].read, default=DEFAULT_GAMMA,
                        help="discount per 0.02 s control step, in [0, 1] (the paper: 0.98)")
    parser.add_argument("--seed", type=SEED.read, default=0,
                        help="goal i of a setting is the env's goal after reset(seed=SEED+i) "
                             "(integer >= 0)")
    parser.add_argument("--grid", type=GRID.read, default=0, metavar="PER_JOINT",
                        help="also check each setting against a brute-force search over a grid "
                             "of PER_JOINT constant angles in [-pi, pi] rad per controlled joint "
                             f"(0: off; skipped where PER_JOINT^n > {BRUTE_MAX_COMMANDS}); "
                             "16 costs about 2 minutes per 3-joint setting here")
    parser.add_argument("--out", type=Path, default=Path("optimality"),
                        help="output folder for optimality.csv and optimality.png")
    parser.add_argument("--curves", nargs="+", type=Path, default=None, metavar="RUNS_ROOT",
                        help="also draw DIR/optimality_curves.png: the learning curves of the "
                             "run folders below these roots beside the shares")
    parser.add_argument("--from-csv", nargs="+", type=Path, default=None, metavar="CSV",
                        help="compute nothing: join these optimality.csv files (e.g. of runs "
                             "made in parallel) into DIR and draw the figures from them")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_force(parser)
    args = parser.parse_args(argv)
    from analysis.runs import find_runs

    try:  # the runs of --curves read before computing: a bad one was found only at the end
        overrides = check_overrides(args.task, args.readings)
        find_runs(args.curves or [])
    except (FileNotFoundError, ValueError) as err:
        parser.error(f"--curves: {err}" if isinstance(err, FileNotFoundError | RunFolderError)
                     else str(err))
    with usage_errors(parser):  # before any computing
        check_files(args.out, ("optimality.csv", "optimality.png", "optimality_curves.png"),
                    "--out")
    settings = args.settings or [(r, n) for r in args.regions for n in args.joints]
    with usage_errors(parser, ValueError):
        rows, skipped = (read_csvs(args.from_csv), []) if args.from_csv else study(
            settings, args.readings, overrides, args.goals, args.gamma, args.seed,
            grid=args.grid, progress=not args.no_progress)
    for line in skipped:
        print(line, file=sys.stderr)
    if not rows:
        print("nothing to do: every reading was skipped", file=sys.stderr)
        return 1
    with write_errors(parser, args.force):
        write_csv(args.out / "optimality.csv", CSV_COLUMNS, rows)
        plot(rows, out=args.out / "optimality.png")
        if args.curves:
            plot_beside_curves(rows, args.curves, args.out / "optimality_curves.png")
    if args.from_csv:
        print(f"joined {len(rows)} rows into {args.out / 'optimality.csv'}")
        return 0
    print(f"{'region':<14}{'n':>2} {'reading':<14}{'worth %':>8} {'95 % CI':>13} "
          f"{'reachable %':>12} {'mean gap':>9} {'grid worth %':>13}")
    for r in rows:
        print(f"{r['region']:<14}{r['joints']:>2} {r['reading']:<14}"
              f"{100 * r['share_worth']:>8.1f} {100 * r['ci_low']:>6.1f}-{100 * r['ci_high']:<6.1f}"
              f"{100 * r['share_reachable']:>12.1f} {r['mean_gap']:>9.1f} "
              + (f"{100 * r['share_worth_grid']:>13.1f}" if r["share_worth_grid"] != ""
                 else f"{'-':>13}"))
    print("constant commands bound a learner's return from below on both sides: the shares "
          "compare settings; they are not what a learner achieves")
    print(f"wrote {args.out / 'optimality.csv'} and {args.out / 'optimality.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
