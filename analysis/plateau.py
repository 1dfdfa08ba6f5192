"""The plateau rule: whether a setting's learning curve, at the budget its runs reached, has
stopped moving enough that a claim about where training ends (at the paper's budget) could be
contradicted there. It never lets such a claim hold before its budget. The window, the slope
under two variance models (*pooled*, *seeds*), the band on the change extrapolated to the
claim's budget, and why each is what it is: docs/design.md, "The plateau rule"; its numbers
are the constants below.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from analysis.paper import PAPER_EPISODES

PLATEAU_WINDOW = 2_000
"""Longest window the slopes are fitted on (training episodes): 10 % of the paper's budget."""

PLATEAU_MIN_SESSIONS = 5
"""Fewest test sessions a window needs to be judged (as many as a level is averaged over)."""

PLATEAU_BAND = 5.0
"""Successes per 100 test goals: the 95 % interval of the change extrapolated to the claim's
budget must lie within +- this, under both models. Half `analysis.report.ABOUT_TOLERANCE` and
equal to `analysis.report.CONVERGED_GAP` (docs/design.md says why)."""

DECIDING_LEVEL = 0.95
"""The level whose intervals decide the rule: a curve whose true extrapolated change is at the
band's edge is called plateaued with probability at most (1 - 0.95) / 2 = 2.5 % per model."""

FALSE_PLATEAU_RATE = (1.0 - DECIDING_LEVEL) / 2.0
"""The rule's stated false-plateau rate at the band's edge (tests/test_plateau.py checks it
by simulation)."""

PLATEAU_STAGES = (1_000, 2_000, 4_000, 8_000, 12_000, 16_000, 20_000)
"""Budgets (training episodes) the rule is applied at, as the long study reaches them."""

MODELS = ("pooled", "seeds")
"""The two variance models, in the order tables print them."""


@functools.lru_cache(maxsize=256)
def t_quantile(q: float, dof: int) -> float:
    """Student-t quantile ``q`` with ``dof`` degrees of freedom (cached: the rule's simulation
    in tests/test_plateau.py asks for the same few thousands of times)."""
    from scipy import stats

    return float(stats.t.ppf(q, dof))


@dataclass(frozen=True)
class Slope:
    """A slope with its standard error and degrees of freedom (successes per 100 per 1,000
    training episodes)."""

    value: float
    stderr: float
    dof: int

    @property
    def p_value(self) -> float:
        """Two-sided Student-t p-value against slope 0."""
        from scipy import stats

        if self.stderr > 0:
            return float(2.0 * stats.t.sf(abs(self.value) / self.stderr, self.dof))
        return 0.0 if self.value != 0 else 1.0

    def interval(self, level: float) -> tuple[float, float]:
        """The two-sided Student-t interval of the slope at ``level`` (per 1,000 episodes)."""
        if not 0.0 < level < 1.0:
            raise ValueError(f"confidence level must be in (0, 1); got {level}")
        half = t_quantile(0.5 + level / 2.0, self.dof) * self.stderr
        return self.value - half, self.value + half


def ols_slope(x: np.ndarray, y: np.ndarray) -> Slope:
    """The least-squares slope of ``y`` on ``x`` (with an intercept), per 1,000 units of x.

    Parameters
    ----------
    x : (n,) float
        Training episodes of the sessions (at least 3 distinct values).
    y : (n,) float
        Successes per 100 test goals (the per-session mean over seeds).

    Returns
    -------
    Slope
        Per 1,000 episodes; its p-value two-sided against 0, with ``n - 2`` degrees of freedom.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.ndim != 1 or x.shape != y.shape:
        raise ValueError(f"x and y must be (n,) arrays of one length; got shapes {x.shape} "
                         f"and {y.shape}")
    if len(np.unique(x)) < 3:
        raise ValueError(f"a slope with an interval needs at least 3 distinct x; got {x.tolist()}")
    dx = x - x.mean()
    sxx = float(dx @ dx)
    slope = float(dx @ (y - y.mean())) / sxx
    resid = y - y.mean() - slope * dx
    dof = len(x) - 2
    return Slope(slope * 1000.0, math.sqrt(float(resid @ resid) / dof / sxx) * 1000.0, dof)


def seed_slope(x: np.ndarray, y: np.ndarray) -> Slope:
    """The mean of each seed's own least-squares slope, its interval from their spread.

    Parameters
    ----------
    x : (n,) float
        Training episodes of the sessions (at least 3 distinct values).
    y : (n_seeds, n) float
        Successes per 100 test goals per seed (at least 2 seeds).

    Returns
    -------
    Slope
        Per 1,000 episodes; standard error sd(slopes) / sqrt(n_seeds), ``n_seeds - 1`` degrees
        of freedom, p-value two-sided against 0 (a one-sample t-test of the seeds' slopes).
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    if y.ndim != 2 or y.shape[1] != len(x) or len(y) < 2:
        raise ValueError(f"y must be (n_seeds >= 2, n) with n = len(x) = {len(x)}; got shape "
                         f"{y.shape}")
    if len(np.unique(x)) < 3:
        raise ValueError(f"a slope with an interval needs at least 3 distinct x; got {x.tolist()}")
    dx = x - x.mean()
    each = (y - y.mean(axis=1, keepdims=True)) @ dx / float(dx @ dx)
    return Slope(float(each.mean()) * 1000.0,
                 float(each.std(ddof=1)) / math.sqrt(len(each)) * 1000.0, len(each) - 1)


@dataclass(frozen=True)
class Plateau:
    """The plateau rule applied to one setting at one budget (see the module docstring)."""

    end: int
    """The last session judged (training episodes)."""
    start: int
    """The window's first session (training episodes)."""
    sessions: int
    """Test sessions in the window."""
    budget: int
    """The claim's budget (training episodes) the slope is extrapolated to."""
    slopes: dict[str, Slope] | None
    """Per model of `MODELS`, per 1,000 episodes (None: too few sessions or seeds)."""

    @property
    def remaining(self) -> int:
        """Training episodes from ``end`` to the claim's budget (0 at or past it)."""
        return max(self.budget - self.end, 0)

    def change(self, model: str, level: float = DECIDING_LEVEL) -> tuple[float, float, float]:
        """The change extrapolated to the budget (slope x remaining): estimate, low, high."""
        if model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}; got {model!r}")
        if self.slopes is None:
            return (math.nan,) * 3
        k = self.remaining / 1000.0
        s = self.slopes[model]
        low, high = s.interval(level)
        return s.value * k, low * k, high * k

    def plateaued_under(self, model: str) -> bool:
        """Enough sessions, and ``model``'s 95 % interval of the extrapolated change inside
        +- `PLATEAU_BAND`."""
        if self.slopes is None or self.sessions < PLATEAU_MIN_SESSIONS:
            return False
        _, low, high = self.change(model)
        return low >= -PLATEAU_BAND and high <= PLATEAU_BAND

    @property
    def plateaued(self) -> bool:
        """The rule's verdict: plateaued under both variance models."""
        return all(self.plateaued_under(m) for m in MODELS)

    def reach(self) -> tuple[float, float]:
        """The widest 95 % extrapolated change over both models: (low, high)."""
        got = [self.change(m)[1:] for m in MODELS]
        return min(g[0] for g in got), max(g[1] for g in got)

    def verdict(self) -> str:
        """'plateaued at N episodes', 'not plateaued at N episodes' or 'at the budget'."""
        if self.remaining == 0:
            return f"at the claim's budget ({self.budget:,} episodes)"
        return (f"plateaued at {self.end:,} episodes" if self.plateaued
                else f"not plateaued at {self.end:,} episodes")


def plateau(episode: np.ndarray, percent: np.ndarray, upto: int | None = None,
            budget: int = PAPER_EPISODES) -> Plateau:
    """The plateau rule on one setting's seeds.

    Parameters
    ----------
    episode : (T,) int
        Training episodes of the seeds' common test sessions, increasing.
    percent : (n_seeds, T) float
        Successes per 100 test goals per seed and session.
    upto : int, optional
        Apply the rule at this budget (training episodes): sessions after it are dropped.
    budget : int
        The claim's budget (training episodes) the slopes are extrapolated to (default: the
        paper's 20,000).
    """
    episode = np.asarray(episode)
    percent = np.asarray(percent, float)
    if episode.ndim != 1 or percent.ndim != 2 or percent.shape[1] != len(episode):
        raise ValueError(f"expected episode (T,) and percent (n_seeds, T); got shapes "
                         f"{episode.shape} and {percent.shape}")
    if len(episode) == 0 or np.any(np.diff(episode) <= 0):
        raise ValueError(f"episode must be non-empty and increasing; got {episode.tolist()}")
    if budget <= 0:
        raise ValueError(f"budget must be a positive number of training episodes; got {budget}")
    if upto is not None:
        keep = episode <= upto
        if not keep.any():
            raise ValueError(f"no test session at or below episode {upto}; the first is at "
                             f"{int(episode[0])}")
        episode, percent = episode[keep], percent[:, keep]
    end = int(episode[-1])
    in_window = episode >= end - min(PLATEAU_WINDOW, end // 2)
    start = int(episode[in_window][0])
    n = int(in_window.sum())
    x, y = episode[in_window], percent[:, in_window]
    slopes = ({"pooled": ols_slope(x, y.mean(axis=0)), "seeds": seed_slope(x, y)}
              if n >= 3 and len(y) >= 2 else None)
    return Plateau(end, start, n, budget, slopes)


def stages(end: int) -> list[int]:
    """The budgets of `PLATEAU_STAGES` the runs reached, and their end if it is none of them."""
    out = [s for s in PLATEAU_STAGES if s <= end]
    return out if out and out[-1] == end else [*out, end]
