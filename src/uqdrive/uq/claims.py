"""Method-level claims: is method A (or its warnings) safer than B over the distribution of its training runs?

Replicate r is one training run of each side (the heads share the replicate's trunk); its two cells drive the
same rollout seeds, so it gives one paired difference Δ̂_r = η̂_A,r − η̂_B,r ∈ [−1, 1]. Replicates are independent
training runs driving disjoint seed blocks, so the Δ̂_r are i.i.d. — the only assumption. Their distribution can
be anything on [−1, 1]: training runs that fail outright make it skewed or bimodal (this project's own runs do),
so nothing here assumes normality. Two estimands, each decided by its own procedure, valid for every such spread:

- **The mean difference** Δ = E[Δ̂_r] = E[η_A,r − η_B,r], the paper's estimand (it compares mean rates) and the
  claim's verdict: the betting interval (`betting.mean_interval`, WSR's stakes tuned for the R runs fixed in
  advance, cap ``CAP``) at the claim's level.
  SUPPORTED "A is safer on average over training runs" when it lies above 0, REFUTED when below, EQUIVALENT
  within ±δ when inside (−δ, δ); each read by the betting test at that point (`betting.rejects`), so each verdict
  is wrong only if Δ lies beyond one end: probability ≤ level/2, whatever the spread. Ten runs at the paper
  family's level never decide it: no valid interval can, when one run in two might fail outright
  (docs/measurements.md: the floor). ``runs_needed`` (`uqdrive.uq.runs_needed`) simulates this procedure to say
  how many runs would.
- **q = P(A's run scores higher than its paired B's | they differ)**, a second, separately worded estimand: the
  exact sign test of q = ½ and its Clopper–Pearson interval (`paired.share_interval`). It is not a property of the
  method alone: q depends on the n rollouts each run's score is read from (more rollouts, fewer ties and fewer
  upsets), and q ≠ ½ says nothing of the mean (A can win most pairs and lose on average).

Levels: a family of m claims has α; the mean verdicts get ``MEAN_SHARE`` of it and the sign verdicts the rest,
each split over the m claims (Bonferroni), so with probability ≥ 1 − α every verdict of both kinds in the family
is right, by the union bound over the 2m intervals — α exactly, in every corner. `tests/test_uq_claims.py`
measures each error by simulation under uniform, Beta, piled, bimodal and failing-run spreads, and where the means
are equal but q ≠ ½.

A continuous per-run score with no bounded range (the margin) has no distribution-free interval for its mean:
its claims carry the sign verdict only (the mean verdict stays undecided, reason: no bounded range) and all of
the family's α goes to the sign tests.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import special

from uqdrive.uq import runs_needed as planning
from uqdrive.uq.betting import mean_interval, rejects
from uqdrive.uq.multiplicity import split_gamma
from uqdrive.uq.paired import PairedTable, share_interval, sign_test_p
from uqdrive.uq.verdict import Reason, Verdict

ASSUMPTION = "none beyond i.i.d. training runs"
POWER = 0.8  # the probability with which the runs needed decide a claim
PLANNED_SHARE = 0.9  # the sign test is planned for A's run being the safer in 9 of 10 differing runs
MEAN_SHARE = 0.5  # of a family's α, for the mean verdicts; the rest for the sign verdicts
CAP = 0.99  # the mean interval's stake cap (any c < 1 is valid): nearest the floor on the study's spread
SIGN_ESTIMAND = "P(a run of A scores higher than its paired run of B | they differ), at n rollouts per run"
MEAN_ESTIMAND = "mean over training runs of η_A − η_B"
CODES = (Verdict.UNDECIDED, Verdict.SUPPORTED, Verdict.REFUTED, Verdict.EQUIVALENT)


@dataclasses.dataclass(frozen=True)
class MethodClaim:
    """ "A is safer than B" over training runs: ``tables[r]`` pairs replicate r's cell A with its cell B on the same
    seeds; ``margin`` is δ, within which the two count as equivalent."""

    name: str
    tables: Mapping[int, PairedTable]
    margin: float

    def differences(self) -> np.ndarray:
        return np.array([t.effect for t in self.tables.values()], float)

    def rollouts(self) -> int:
        return min(t.n for t in self.tables.values())


@dataclasses.dataclass(frozen=True)
class ScoreClaim:
    """ "A scores higher than B" over training runs on an unbounded per-run score (e.g. the margin):
    ``differences[r]``: replicate r's per-run score of A minus B's on the same seeds; decided by the sign test
    on each replicate's mean difference."""

    name: str
    differences: Mapping[int, np.ndarray]
    margin: float

    def per_replicate(self) -> np.ndarray:
        return np.array([np.mean(d) for d in self.differences.values()], float)

    def rollouts(self) -> int:
        return min(len(d) for d in self.differences.values())


@dataclasses.dataclass(frozen=True)
class ClaimResult:
    """One method claim decided; its ``verdict`` is for the mean.

    Mean (the paper's estimand, the headline): ``estimate`` (the replicates' mean difference), its betting interval
    ``low``/``high`` at ``level`` (None for an unbounded score), ``verdict`` and ``reason``; ``runs_needed`` /
    ``runs_needed_worst``: training runs at which this procedure decides it with probability 0.8 under the
    spread the replicates show (resampled) / under the worst spread with that mean (None once decided, for an
    unbounded score, or past `runs_needed.MOST`). Sign (q, the second line): ``ahead``/``behind``: runs in which
    A's/B's score is the higher, of ``rollouts`` rollouts per run; ``share_low``/``share_high``: the interval for q
    at ``sign_level``; ``p_value``: the exact two-sided sign test of q = ½; ``sign_verdict``;
    ``differing_runs_needed``: differing runs at which it decides with probability 0.8 when A's run is the safer
    in 9 of 10 (None once decided)."""

    name: str
    estimate: float
    low: float | None
    high: float | None
    verdict: Verdict
    reason: Reason
    runs_needed: int | None
    runs_needed_worst: int | None
    ahead: int
    behind: int
    share_low: float
    share_high: float
    p_value: float
    sign_verdict: Verdict
    differing_runs_needed: int | None
    rollouts: int
    replicates: tuple[int, ...]
    level: float
    sign_level: float
    alpha: float
    margin: float
    estimand: str
    sign_estimand: str
    assumption: str


def sign_runs_needed(level: float, power: float = POWER, share: float = PLANNED_SHARE) -> int:
    """Fewest differing runs m at which the exact two-sided sign test at ``level`` rejects on A's side with
    probability ≥ ``power`` when each differing run favours A with probability ``share`` (exact binomial sums)."""
    for m in range(1, 100_000):
        k = np.arange(m + 1)
        rejects_at = 2 * special.bdtrc(k - 1, m, 0.5) <= level  # P(X ≥ k) under ½, doubled
        if rejects_at.any():
            first = int(np.argmax(rejects_at))
            if special.bdtrc(first - 1, m, share) >= power:
                return m
    raise ValueError(f"no run count up to 100000 reaches power {power} at level {level}")


def mean_verdicts(differences, level: float, margin: float) -> np.ndarray:
    """The mean verdict of every row of per-run differences on [−1, 1] (last axis: the runs, in replicate order),
    as an index into ``CODES``: the betting tests at 0 (either side) and at ±δ, the same stakes as the interval
    (WSR's fixed-R tuning: R, the runs, is fixed before the data)."""
    tests = ((0.0, True), (0.0, False), (-margin, True), (margin, False))
    above, below, low, high = rejects(differences, -1.0, 1.0, level, tests, np.shape(differences)[-1], CAP)
    inside = low & high
    return np.where(above, 1, np.where(below, 2, np.where(inside, 3, 0)))


def _sign(differences: np.ndarray, level: float) -> tuple[int, int, float, float, float, Verdict]:
    ahead, behind = int(np.sum(differences > 0)), int(np.sum(differences < 0))
    low, high = share_interval(ahead, ahead + behind, level)
    verdict = Verdict.SUPPORTED if low > 0.5 else Verdict.REFUTED if high < 0.5 else Verdict.UNDECIDED
    return ahead, behind, low, high, sign_test_p(ahead, ahead + behind), verdict


def _needed(differences: np.ndarray, level: float, margin: float, sims: int) -> tuple[int | None, int | None]:
    def decided(x: np.ndarray) -> np.ndarray:
        return mean_verdicts(x, level, margin) > 0

    spreads = planning.resampled(differences), planning.worst(float(differences.mean()))
    return tuple(planning.runs_needed(decided, spread, sims) for spread in spreads)


def decide_claim(claim: MethodClaim | ScoreClaim, level: float, sign_level: float, sims: int = 0) -> ClaimResult:
    """One claim: its mean verdict at ``level``, its sign verdict at ``sign_level``; ``sims`` > 0: the runs needed
    from that many simulated studies per run count (0: not computed)."""
    bounded = isinstance(claim, MethodClaim)
    differences = claim.differences() if bounded else claim.per_replicate()
    replicates = tuple(claim.tables if bounded else claim.differences)
    ahead, behind, share_low, share_high, p, sign_verdict = _sign(differences, sign_level)
    low = high = None
    verdict, reason = Verdict.UNDECIDED, Reason.NO_BOUNDED_RANGE
    if bounded:
        interval = mean_interval(differences, -1.0, 1.0, level, horizon=len(differences), cap=CAP)
        low, high = float(interval.low), float(interval.high)
        verdict = CODES[int(mean_verdicts(differences, level, claim.margin))]
        reason = Reason.TOO_FEW_REPLICATES if len(replicates) < 2 else Reason.NOT_DECIDED
        reason = Reason.DECIDED if verdict is not Verdict.UNDECIDED else reason
    needed = _needed(differences, level, claim.margin, sims) if bounded and sims and reason else (None, None)
    return ClaimResult(
        claim.name,
        float(differences.mean()),
        low,
        high,
        verdict,
        reason,
        *needed,
        ahead,
        behind,
        share_low,
        share_high,
        p,
        sign_verdict,
        None if sign_verdict is not Verdict.UNDECIDED else sign_runs_needed(sign_level),
        claim.rollouts(),
        replicates,
        float(level),
        float(sign_level),
        float("nan"),
        float(claim.margin),
        MEAN_ESTIMAND if bounded else "",
        SIGN_ESTIMAND,
        ASSUMPTION,
    )


def family_levels(alpha: float, claims: Sequence[MethodClaim | ScoreClaim]) -> tuple[float, float]:
    """Each claim's mean level and sign level in a family of m claims at α: ``MEAN_SHARE`` of α over the m mean
    verdicts, the rest over the m sign verdicts (all α to the sign verdicts where no claim has a bounded range)."""
    share = MEAN_SHARE if any(isinstance(c, MethodClaim) for c in claims) else 0.0
    mean = split_gamma(alpha * share, len(claims)) if share else 0.0
    return mean, split_gamma(alpha * (1 - share), len(claims))


def decide_claims(claims: Sequence[MethodClaim | ScoreClaim], alpha: float, sims: int = 0) -> list[ClaimResult]:
    """A family of method claims at family-wise error α over both estimands' verdicts (`family_levels`): with
    probability ≥ 1 − α every SUPPORTED, REFUTED and EQUIVALENT verdict, of the mean or of q, is right, whatever
    the training runs do. ``sims``: simulated studies per run count for the runs needed (0: none; the findings
    use `runs_needed.SIMS`)."""
    if not claims or any(not (c.tables if isinstance(c, MethodClaim) else c.differences) for c in claims):
        raise ValueError("method claims need at least one claim, each with at least one replicate's table")
    mean, sign = family_levels(alpha, claims)
    return [dataclasses.replace(decide_claim(c, mean or sign, sign, sims), alpha=float(alpha)) for c in claims]
