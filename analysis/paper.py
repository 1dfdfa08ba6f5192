"""What Lewis, Moll and Kavraki (2019) report for each setting, and the orderings they claim.

The paper gives its results as curves and sentences, not tables; the numbers here are the
asymptotic success rates its text states (section IV), with the sentence they come from.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PaperResult:
    """The paper's statement about one setting."""

    approx_success: float | None
    """Asymptotic successes out of 100 test goals the text states (None: not stated)."""
    text: str
    """What the paper says, briefly."""


PAPER_RESULTS: dict[tuple[str, int], PaperResult] = {
    ("unconstrained", 2): PaperResult(None, "a highly capable policy"),
    **{("unconstrained", n): PaperResult(40.0, "under 50 %, about 40 % asymptotically")
       for n in (3, 4, 5, 6)},
    ("zheight", 3): PaperResult(20.0, "about 20 % asymptotically"),
    ("zheight", 6): PaperResult(20.0, "about 20 %, slower to converge"),
    ("closebox", 3): PaperResult(20.0, "about 20 % asymptotically"),
    ("closebox", 6): PaperResult(20.0, "about 20 %, slower to converge"),
    ("farbox", 3): PaperResult(100.0, "nearly 100 % within 1,000 episodes, all 5 runs"),
    ("farbox", 6): PaperResult(100.0, "nearly 100 % within 1,000 episodes, 4 of 5 runs"),
    ("farbox_tall", 3): PaperResult(100.0, "similar to farbox"),
    ("farbox_tall", 6): PaperResult(100.0, "similar to farbox"),
}
"""(region, joints) -> what the paper reports."""

PAPER_GRID: tuple[tuple[str, int], ...] = (
    *(("unconstrained", n) for n in range(2, 7)),
    *((region, n) for region in ("zheight", "closebox", "farbox") for n in (3, 6)),
)
"""The settings of the paper's figures 3 and 4: 11 settings, 5 seeds each in the paper."""

PAPER_SEEDS = 5
PAPER_EPISODES = 20_000
HIGH_SUCCESS = 90.0
"""Successes out of 100 that count as "learned" (the episode where it is first reached)."""
