"""What Lewis, Moll and Kavraki (2019) report for each setting, and every claim of its results.

The paper gives its results as curves and sentences, not tables; the numbers here are the
asymptotic success rates its text states (section IV), and `CLAIMS` quotes each claim of
section IV in the paper's own words with the figure it rests on. Its figures: Fig. 1 is
FetchReach's goal region (not a result), Fig. 2 the unconstrained curves (2-6 joints), Fig. 3
the z-height, close box and far box curves (3 and 6 joints), Fig. 4 the success maps of two
unconstrained 3-joint policies. How each claim is judged: `analysis.report`.
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
"""The settings of the paper's Figs. 2 and 3: 11 settings, 5 seeds each in the paper."""

PAPER_SEEDS = 5
PAPER_EPISODES = 20_000
HIGH_SUCCESS = 90.0
"""Successes out of 100 that count as "highly capable" and "nearly 100 %" (our reading; the
paper gives no number)."""

UNDER_SUCCESS = 50.0
"""Unconstrained with 3-6 joints: DDPG "fails to learn a policy that can hit more than 50% of the
sampled goal locations" (section IV-A)."""

FAST_EPISODES = 1000
"""The far box's speed: "nearly 100% success within 10 testing sessions, or 1000 training
episodes" (section IV-C)."""

FAST_MISSES = {3: 0, 6: 1}
"""Joints -> far-box runs of the paper's 5 that did not reach nearly 100 % by `FAST_EPISODES`:
"for all independent runs in the 3 joint case, and for 4 of 5 runs in the 6 joint case"."""


@dataclass(frozen=True)
class PaperClaim:
    """One claim of the paper's results, in its words."""

    name: str
    """Short name, as reports print it."""
    words: str
    """The paper's words (quoted from section IV; an ellipsis marks a cut)."""
    where: str
    """Section and figure."""
    at_end: bool
    """A claim about where training ends (asymptotes, converged levels, convergence): only
    runs of the paper's `PAPER_EPISODES` can show it."""


CLAIMS: tuple[PaperClaim, ...] = (
    PaperClaim("far box near 100 % by 1,000 episodes, 3 joints",
               "Learning converges to nearly 100% success within 10 testing sessions, or 1000 "
               "training episodes, for all independent runs in the 3 joint case",
               "IV-C, Fig. 3", False),
    PaperClaim("far box near 100 % by 1,000 episodes, 6 joints",
               "... and for 4 of 5 runs in the 6 joint case (1 run experienced the type of "
               "catastrophic forgetting that DDPG is known for)", "IV-C, Fig. 3", False),
    PaperClaim("far box easier than the other regions",
               "the far box constraint is easier to learn than any of the previously considered "
               "goal regions", "IV-C, Figs. 2-3", False),
    PaperClaim("unconstrained 2 joints highly capable",
               "DDPG succeeds in learning a highly capable policy for 2 joint control",
               "IV-A, Fig. 2", True),
    PaperClaim("unconstrained 3-6 joints under 50 %",
               "for 3–6 joints DDPG fails to learn a policy that can hit more than 50% of the "
               "sampled goal locations", "IV-A, Fig. 2", True),
    PaperClaim("unconstrained 3-6 joints about 40 %",
               "the asymptotic success rate ... decreases from approximately 40% in the "
               "unconstrained case", "IV-B, Figs. 2-3", True),
    PaperClaim("unconstrained 3-6 joints alike",
               "the asymptotic behavior of DDPG is approximately equivalent for 3–6 joints",
               "IV-A, Fig. 2", True),
    PaperClaim("zheight and closebox about 20 %",
               "... to 20% in the z-height and close box constrained cases", "IV-B, Fig. 3",
               True),
    PaperClaim("zheight and closebox identical",
               "the asymptotic performance of DDPG on these constraint regions is identical",
               "IV-B, Fig. 3", True),
    PaperClaim("unconstrained above zheight and closebox",
               "the asymptotic success rate of the policy learned by DDPG decreases from "
               "approximately 40% in the unconstrained case to 20% in the z-height and close "
               "box constrained cases", "IV-B, Figs. 2-3", True),
    PaperClaim("6 joints slower to converge than 3 (zheight, closebox)",
               "we can qualitatively observe that learning takes longer to converge for 6 joint "
               "control", "IV-B, Fig. 3", True),
    PaperClaim("far box 1.0 m tall like the far box",
               "an extension of the height of the far box constraint region to 1.0 meters "
               "resulted in a convergent success rate similar to that in the reported far box "
               "case", "IV-C (no figure)", True),
    PaperClaim("two converged unconstrained 3-joint policies, distinct success regions",
               "two convergent (~40% success) policies ... display very distinct regions of "
               "competence", "IV-D, Fig. 4", True),
)
"""Every claim of the paper's section IV, in the order of `analysis.report`'s checks."""
