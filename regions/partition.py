"""Partitions of a goal set into M cells, for the regional ensemble (issue 25): k-means on goals
drawn from the task's own goal distribution; a goal belongs to the cell of its nearest centre.

k-means rather than fixed sectors (azimuth x height) because it adapts to any region (a sector
grid over the far box would leave most sectors empty), gives cells of about equal probability
under the goal distribution (so members that share the update budget equally also see about
equal shares of the goals), keeps each cell compact in space (a "region of competence" in the
paper's words), and works in any goal dimension (the toy env's too).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ur5kin.checks import integer


@dataclass(frozen=True)
class KMeansSettings:
    """How the cells are fitted; each number is part of the partition a run records."""

    goals: int = 4096
    """Goals drawn from the task's goal distribution to fit the centres (at 4 cells about
    1,000 per cell: the centres move by about 1 % of a cell's width between draws)."""
    seed: int = 20190916
    """Seed of those draws and of the k-means++ start: the same for every run seed, so all runs
    of a task share one partition (the partition is part of the algorithm, not of the run)."""
    max_iterations: int = 300
    """Lloyd iterations at most; they stop earlier when no goal changes its cell."""

    def __post_init__(self) -> None:
        if self.goals < 1 or self.max_iterations < 1 or self.seed < 0:
            raise ValueError(f"bad k-means settings: {self!r}")


KMEANS = KMeansSettings()
"""The settings every ensemble uses (the defaults)."""


def nearest_cell(goals: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """The cell of each goal: the index of its nearest centre (ties: the lowest index).

    goals : (..., d) float, m; centres : (M, d) float, m -> (...) int.
    """
    goals = np.asarray(goals, dtype=np.float64)
    d2 = np.square(goals[..., None, :] - np.asarray(centres, dtype=np.float64)).sum(-1)
    return np.argmin(d2, axis=-1)


def kmeans(goals: np.ndarray, m: int, rng: np.random.Generator, max_iterations: int = 300
           ) -> np.ndarray:
    """Centres (m, d) of k-means (Lloyd's iterations from a k-means++ start) on ``goals``.

    goals : (n, d) float, n >= m distinct points. A cell left empty by an iteration gets the
    goal farthest from its own centre, so every cell of the result holds goals. The centres
    are returned in lexicographic order of their coordinates, so cell i names the same place
    however the start fell.

    Raises
    ------
    ValueError
        When ``goals`` is not (n, d) finite with at least ``m`` distinct rows, or m < 1.
    """
    goals = np.asarray(goals, dtype=np.float64)
    if goals.ndim != 2 or not np.isfinite(goals).all():
        raise ValueError(f"goals must be (n, d) finite numbers, got shape {goals.shape}")
    m = integer(1, note="cells")("m", m)
    if len(np.unique(goals, axis=0)) < m:
        raise ValueError(f"need at least {m} distinct goals for {m} cells, got "
                         f"{len(np.unique(goals, axis=0))}")
    # k-means++ (Arthur and Vassilvitskii 2007): each next centre drawn with probability
    # proportional to the squared distance to the nearest centre so far
    centres = [goals[rng.integers(len(goals))]]
    d2 = np.square(goals - centres[0]).sum(-1)
    for _ in range(1, m):
        centres.append(goals[rng.choice(len(goals), p=d2 / d2.sum())])
        d2 = np.minimum(d2, np.square(goals - centres[-1]).sum(-1))
    c = np.array(centres)
    cell = nearest_cell(goals, c)
    for _ in range(max_iterations):
        for i in range(m):
            members = goals[cell == i]
            if len(members):
                c[i] = members.mean(0)
            else:  # an empty cell takes the goal worst served by its centre
                far = np.square(goals - c[cell]).sum(-1)
                c[i] = goals[np.argmax(far)]
        new = nearest_cell(goals, c)
        if np.array_equal(new, cell):
            break
        cell = new
    return c[np.lexsort(c.T[::-1])]


@dataclass(frozen=True, eq=False)
class Partition:
    """M cells of a goal set: goal g lies in cell ``argmin_i |g - centres[i]|`` (a Voronoi
    partition of space, so it covers every goal, also one outside the fitted set).

    centres : (M, d) float, m, world frame (the goals' frame).
    """

    centres: np.ndarray
    settings: KMeansSettings = KMEANS

    def __post_init__(self) -> None:
        c = np.asarray(self.centres, dtype=np.float64)
        if c.ndim != 2 or len(c) < 1 or not np.isfinite(c).all():
            raise ValueError(f"centres must be (M, d) finite numbers, got shape {c.shape}")
        object.__setattr__(self, "centres", c)

    @property
    def cells(self) -> int:
        return len(self.centres)

    def cell(self, goals: np.ndarray) -> np.ndarray:
        """`nearest_cell` of ``goals`` (..., d) -> (...) int."""
        return nearest_cell(goals, self.centres)

    def to_dict(self) -> dict[str, Any]:
        """What a run's ``spec.json`` records: the method, its settings and the centres."""
        s = self.settings
        return {"method": "kmeans", "cells": self.cells, "goals": s.goals, "seed": s.seed,
                "max_iterations": s.max_iterations, "centres": self.centres.tolist()}


def fit_partition(goals: np.ndarray, m: int, settings: KMeansSettings = KMEANS) -> Partition:
    """The k-means `Partition` of ``goals`` (n, d) into ``m`` cells, the start drawn from
    ``settings.seed``: the same goals give the same partition."""
    rng = np.random.default_rng(settings.seed)
    return Partition(kmeans(goals, m, rng, settings.max_iterations), settings)
