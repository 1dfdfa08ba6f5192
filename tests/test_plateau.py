"""analysis.plateau: the OLS slope against scipy and numpy, and the plateau rule on synthetic
curves of known slope; analysis.report judges a plateaued setting at its plateau."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from analysis import plateau as pl
from analysis import report
from analysis.paper import CLAIMS


def _curves(slope_per_1000: float, end: int = 4_000, seeds: int = 5, noise: float = 1.0,
            seed: int = 0, base: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    """Sessions every 100 episodes to ``end``: a line of the given slope plus Gaussian noise."""
    rng = np.random.default_rng(seed)
    episode = np.arange(100, end + 1, 100)
    line = base + slope_per_1000 * episode / 1000.0
    return episode, line + rng.normal(0.0, noise, (seeds, len(episode)))


def test_ols_slope_is_scipys_and_numpys() -> None:
    episode, percent = _curves(3.0, noise=4.0)
    y = percent.mean(axis=0)
    got = pl.ols_slope(episode, y)
    ref = stats.linregress(episode, y)
    assert got.value == pytest.approx(ref.slope * 1000)
    assert got.stderr == pytest.approx(ref.stderr * 1000)
    assert got.p_value == pytest.approx(ref.pvalue)
    assert got.value == pytest.approx(np.polyfit(episode, y, 1)[0] * 1000)
    # the 95 % interval from polyfit's covariance (unscaled by n - 2 in its own way)
    _, cov = np.polyfit(episode, y, 1, cov=True)
    half = stats.t.ppf(0.975, len(y) - 2) * np.sqrt(cov[0, 0]) * 1000
    low, high = got.interval(0.95)
    assert (low, high) == pytest.approx((got.value - half, got.value + half))
    # a straight line: its slope exactly, no spread
    exact = pl.ols_slope(episode, 7.0 + 2.5 * episode / 1000.0)
    assert exact.value == pytest.approx(2.5) and exact.stderr == pytest.approx(0.0, abs=1e-9)


def test_the_rule_finds_a_known_slope_and_judges_it() -> None:
    # flat after a rise that ended before the window: plateaued; the fit sees only the window
    episode, percent = _curves(0.0, end=6_000, noise=2.0)
    percent[:, episode < 3_000] -= 10.0
    got = pl.plateau(episode, percent)
    assert (got.start, got.end, got.sessions) == (4_000, 6_000, 21)
    assert got.plateaued and got.verdict() == "plateaued at 6,000 episodes"
    assert got.change()[1] > -pl.PLATEAU_BAND and got.change()[2] < pl.PLATEAU_BAND
    # 10 per 1,000 episodes: the fitted slope is near it, and the curve has not plateaued
    episode, percent = _curves(10.0, end=6_000, noise=2.0)
    got = pl.plateau(episode, percent)
    low, high = got.slope.interval(0.95)
    assert low < 10.0 < high and got.change()[0] == pytest.approx(2 * got.slope.value)
    assert not got.plateaued and got.verdict() == "not judgeable at 6,000 episodes"
    # the last-5 level change: the line's 2,000 episodes x 10 per 1,000, per seed
    assert got.level_change[0] == pytest.approx(20.0, abs=2.0)
    assert got.level_change[3] < got.level_change[1] < got.level_change[0] < \
        got.level_change[2] < got.level_change[4]


def test_the_window_is_the_last_half_at_most_2000_episodes() -> None:
    episode, percent = _curves(0.0, end=20_000)
    assert pl.plateau(episode, percent).start == 18_000
    assert pl.plateau(episode, percent, upto=2_000).start == 1_000
    assert pl.plateau(episode, percent, upto=2_000).sessions == 11
    # a budget between sessions ends at the last session before it
    assert pl.plateau(episode, percent, upto=1_050).end == 1_000
    assert pl.stages(20_000) == list(pl.PLATEAU_STAGES)
    assert pl.stages(2_500) == [1_000, 2_000, 2_500]


def test_flat_but_too_noisy_or_too_short_is_not_a_plateau() -> None:
    # no slope, but a 95 % interval wider than the band: not shown flat, so not judgeable
    episode, percent = _curves(0.0, end=2_000, noise=25.0, seed=3)
    got = pl.plateau(episode, percent)
    assert got.slope.p_value > 0.05 and not got.plateaued
    # a small rise that the 65 % interval would call flat but the 95 % does not
    episode, percent = _curves(3.0, end=2_000, noise=4.0, seed=5)
    got = pl.plateau(episode, percent)
    c65, c95 = got.change(0.65), got.change(0.95)
    assert c65[1] >= -pl.PLATEAU_BAND and c65[2] <= pl.PLATEAU_BAND
    assert c95[2] > pl.PLATEAU_BAND and not got.plateaued
    # four sessions in the window: too few, however flat
    flat = np.full((5, 7), 30.0) + np.arange(7) % 2
    got = pl.plateau(np.arange(100, 701, 100), flat)
    assert got.sessions == 4 and not got.plateaued


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="increasing"):
        pl.plateau(np.array([100, 100, 200]), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"percent \(n_seeds, T\)"):
        pl.plateau(np.array([100, 200]), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="no test session at or below episode 50"):
        pl.plateau(np.array([100, 200]), np.zeros((2, 2)), upto=50)
    with pytest.raises(ValueError, match="at least 3 distinct x"):
        pl.ols_slope(np.array([1.0, 1.0, 2.0]), np.zeros(3))
    assert pl.PLATEAU_BAND == report.CONVERGED_GAP


def _curve_set(slopes: dict[tuple[str, int], float], end: int = 4_000
               ) -> dict[tuple[str, int], report.Curves]:
    out = {}
    for i, (key, slope) in enumerate(slopes.items()):
        episode, percent = _curves(slope, end=end, noise=1.0, seed=i, base=20.0)
        out[key] = report.Curves(episode, percent)
    return out


def test_report_judges_a_claim_at_the_plateau_only_when_every_setting_plateaued() -> None:
    at_20 = _curve_set({("zheight", 3): 0.0, ("closebox", 3): 0.0})
    plateaus = {k: pl.plateau(c.episode, c.percent) for k, c in at_20.items()}
    assert all(p.plateaued for p in plateaus.values())
    checks = {c.claim: c for c in report.judge_claims(at_20, plateaus=plateaus)}
    about = checks["zheight and closebox about 20 %"]
    assert about.verdict is report.Verdict.YES and about.plateau_at == 4_000
    assert about.detail.startswith("judged at the plateau of every setting it compares "
                                   "(4,000 episodes")
    # without the rule (as analysis.sensitivity calls it): not judgeable below 20,000
    plain = {c.claim: c for c in report.judge_claims(at_20)}
    assert plain["zheight and closebox about 20 %"].verdict is report.Verdict.NOT_JUDGEABLE
    # one setting still rising: the claim is not judgeable at 4,000 episodes, naming it
    mixed = _curve_set({("zheight", 3): 8.0, ("closebox", 3): 0.0})
    plateaus = {k: pl.plateau(c.episode, c.percent) for k, c in mixed.items()}
    checks = {c.claim: c for c in report.judge_claims(mixed, plateaus=plateaus)}
    got = checks["zheight and closebox identical"]
    assert got.verdict is report.Verdict.NOT_JUDGEABLE and got.plateau_at is None
    assert "not plateaued by the plateau rule: zheight 3." in got.detail
    # claims not about the end of training are untouched by the rule
    assert [c.claim for c in checks.values()] == [c.name for c in CLAIMS]
