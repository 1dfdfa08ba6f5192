"""The plateau rule: whether a setting's learning curve has stopped moving at the budget its runs
reached, so that its level may be judged there (labelled with that budget) instead of at the
paper's 20,000 episodes.

The rule (docs/design.md, "What the paper reports"), written at the long study's 2,000-episode
stage after a first look at its slopes and fixed from there on:

- The window is the last half of the run, at most `PLATEAU_WINDOW` training episodes: every
  common test session at or after ``end - min(PLATEAU_WINDOW, end // 2)``.
- On it, the ordinary least-squares slope of the per-session mean over seeds against the
  training episode, with its two-sided Student-t intervals (``n - 2`` degrees of freedom) at
  65 % and 95 %, and its p-value against slope 0.
- The fitted change over the window is the slope times the window's length (episodes).
- A setting has **plateaued** when the window holds at least `PLATEAU_MIN_SESSIONS` sessions and
  the 95 % interval of the fitted change lies inside +- `PLATEAU_BAND` successes per 100: the
  curve is shown to move by less than the band over the window, not merely not shown to move.
- Beside it, as information: the change of each seed's last-5 level (its mean over its last 5
  sessions) from the window's start to its end, with the mean over seeds and its 65 % and 95 %
  Student-t intervals.

The OLS interval treats the sessions' residuals as independent; a curve's neighbouring sessions
share a policy's slowly changing weights, so the interval is if anything too narrow, which the
95 % level and the band's requirement on the whole interval are there to offset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PLATEAU_WINDOW = 2_000
"""Longest window the slope is fitted on (training episodes): the issue's 'last 2,000
episodes', 10 % of the paper's budget."""

PLATEAU_MIN_SESSIONS = 5
"""Fewest test sessions a window needs to be judged (as many as a level is averaged over)."""

PLATEAU_BAND = 5.0
"""Successes per 100 test goals: the 95 % interval of the fitted change over the window must lie
within +- this. The same 5 per 100 as `analysis.report.CONVERGED_GAP`, the project's gap for 'a
seed has converged'."""

PLATEAU_LEVELS = (0.65, 0.95)
"""Confidence levels of the slope's intervals: the paper's figures' 65 % and the 95 % the rule
decides on."""

DECIDING_LEVEL = 0.95
"""The level whose interval of the fitted change decides the rule."""

PLATEAU_STAGES = (1_000, 2_000, 4_000, 8_000, 12_000, 16_000, 20_000)
"""Budgets (training episodes) the rule is applied at, as the long study reaches them."""

LEVEL_SESSIONS = 5
"""A seed's level is its mean over its last 5 test sessions (`analysis.report.LAST_SESSIONS`)."""


@dataclass(frozen=True)
class Slope:
    """An OLS slope with its standard error, intervals and p-value (successes per 100 per
    1,000 training episodes)."""

    value: float
    stderr: float
    dof: int
    p_value: float

    def interval(self, level: float) -> tuple[float, float]:
        """The two-sided Student-t interval of the slope at ``level`` (per 1,000 episodes)."""
        from scipy import stats

        if not 0.0 < level < 1.0:
            raise ValueError(f"confidence level must be in (0, 1); got {level}")
        half = float(stats.t.ppf(0.5 + level / 2.0, self.dof)) * self.stderr
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
        Per 1,000 episodes; its p-value two-sided against slope 0, with ``n - 2`` degrees of
        freedom.
    """
    from scipy import stats

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
    stderr = math.sqrt(float(resid @ resid) / dof / sxx)
    p = (float(2.0 * stats.t.sf(abs(slope) / stderr, dof)) if stderr > 0
         else 0.0 if slope != 0 else 1.0)
    return Slope(slope * 1000.0, stderr * 1000.0, dof, p)


@dataclass(frozen=True)
class Plateau:
    """The plateau rule applied to one setting at one budget (see the module docstring)."""

    end: int
    """The last session judged (training episodes): the budget."""
    start: int
    """The window's first session (training episodes)."""
    sessions: int
    """Test sessions in the window."""
    slope: Slope | None
    """Of the per-session mean over seeds, per 1,000 episodes (None: too few sessions)."""
    level_change: tuple[float, float, float, float, float] | None
    """Each seed's last-5 level at ``end`` minus at ``start``: mean over seeds, 65 % low, high,
    95 % low, high (None: fewer than 5 sessions up to ``start``)."""

    @property
    def span(self) -> int:
        """The window's length (training episodes)."""
        return self.end - self.start

    def change(self, level: float = DECIDING_LEVEL) -> tuple[float, float, float]:
        """The fitted change over the window (slope x span): estimate, low, high at ``level``."""
        if self.slope is None:
            return (math.nan,) * 3
        k = self.span / 1000.0
        low, high = self.slope.interval(level)
        return self.slope.value * k, low * k, high * k

    @property
    def plateaued(self) -> bool:
        """The rule's verdict: enough sessions, and the 95 % interval of the fitted change
        inside +- `PLATEAU_BAND`."""
        if self.slope is None or self.sessions < PLATEAU_MIN_SESSIONS:
            return False
        _, low, high = self.change(DECIDING_LEVEL)
        return low >= -PLATEAU_BAND and high <= PLATEAU_BAND

    def verdict(self) -> str:
        """'plateaued at N episodes' or 'not judgeable at N episodes'."""
        return (f"plateaued at {self.end:,} episodes" if self.plateaued
                else f"not judgeable at {self.end:,} episodes")


def plateau(episode: np.ndarray, percent: np.ndarray, upto: int | None = None) -> Plateau:
    """The plateau rule on one setting's seeds.

    Parameters
    ----------
    episode : (T,) int
        Training episodes of the seeds' common test sessions, increasing.
    percent : (n_seeds, T) float
        Successes per 100 test goals per seed and session.
    upto : int, optional
        Apply the rule at this budget (training episodes): sessions after it are dropped.
    """
    from scipy import stats

    episode = np.asarray(episode)
    percent = np.asarray(percent, float)
    if episode.ndim != 1 or percent.ndim != 2 or percent.shape[1] != len(episode):
        raise ValueError(f"expected episode (T,) and percent (n_seeds, T); got shapes "
                         f"{episode.shape} and {percent.shape}")
    if len(episode) == 0 or np.any(np.diff(episode) <= 0):
        raise ValueError(f"episode must be non-empty and increasing; got {episode.tolist()}")
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
    slope = (ols_slope(episode[in_window], percent[:, in_window].mean(axis=0)) if n >= 3
             else None)
    before = episode <= start
    change = None
    if before.sum() >= LEVEL_SESSIONS and len(percent) >= 2:
        diff = (percent[:, -LEVEL_SESSIONS:].mean(axis=1)
                - percent[:, before][:, -LEVEL_SESSIONS:].mean(axis=1))
        se = diff.std(ddof=1) / math.sqrt(len(diff))
        bounds = []
        for level in PLATEAU_LEVELS:
            half = float(stats.t.ppf(0.5 + level / 2.0, len(diff) - 1)) * se
            bounds += [diff.mean() - half, diff.mean() + half]
        change = (float(diff.mean()), *(float(b) for b in bounds))
    return Plateau(end, start, n, slope, change)


def stages(end: int) -> list[int]:
    """The budgets of `PLATEAU_STAGES` the runs reached, and their end if it is none of them."""
    out = [s for s in PLATEAU_STAGES if s <= end]
    return out if out and out[-1] == end else [*out, end]
