"""Method-level claims: is method A (or its warnings) safer than B over the distribution of its training runs?

Replicate r is one training run of each side (the heads share the replicate's trunk); its two cells drive the
same rollout seeds, so it gives one paired difference Δ̂_r = η̂_A,r − η̂_B,r ∈ [−1, 1]. Replicates are independent
training runs driving disjoint seed blocks, so the Δ̂_r are i.i.d. — the only assumption. Their distribution can
be anything on [−1, 1]: training runs that fail outright make it skewed or bimodal (this project's own runs do),
so nothing here assumes normality. Two estimands, each with a procedure valid for every such distribution:

- **P(A's run is the safer)**: among training runs whose paired scores differ, the share q in which A's is the
  higher (Δ̂_r > 0; the rollout budget n is part of the score). Exact sign test of q = ½ and its Clopper–Pearson
  interval (reconciled with the test, `paired.share_interval`): SUPPORTED "A is safer" when the interval lies
  above ½, REFUTED (B is) when below. Ten runs decide it only when nine or ten differing runs agree.
- **The mean difference** Δ = E[Δ̂_r] = E[η_A,r − η_B,r]: the betting interval (`betting.mean_interval`), valid for
  every distribution on [−1, 1]. EQUIVALENT within ±δ only when that interval lies inside (−δ, δ). With ten runs
  it never does: no procedure free of assumptions bounds a mean tightly from ten runs when one run in twenty may
  fail outright. Where a claim is undecided, ``runs_needed`` says how many would decide it (below).

Each verdict is wrong only if the truth lies beyond one end of one interval at level 1 − α_claim, probability
≤ α_claim/2 whatever the spread; `decide_claims` puts each of m claims at α/m (Bonferroni), so with probability
≥ 1 − α every verdict of the family is right. `tests/test_uq_claims.py` measures each error by simulation under
uniform, Beta, piled, bimodal and failing-run spreads, and shows Student's t failing there.

A continuous per-run score with no bounded range (the margin) has no distribution-free interval for its mean:
its claims are decided by the sign test alone and are never called equivalent.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import special

from uqdrive.uq.betting import mean_interval
from uqdrive.uq.multiplicity import split_gamma
from uqdrive.uq.paired import PairedTable, share_interval, sign_test_p
from uqdrive.uq.verdict import Reason, Verdict

ASSUMPTION = "none beyond i.i.d. training runs"
POWER = 0.8  # the probability with which the runs needed decide a claim
PLANNED_SHARE = 0.9  # the sign test is planned for A's run being the safer in 9 of 10 differing runs
SIGN_ESTIMAND = "P(a run of A scores higher than its paired run of B | they differ)"
MEAN_ESTIMAND = "mean over training runs of η_A − η_B"


@dataclasses.dataclass(frozen=True)
class MethodClaim:
    """ "A is safer than B" over training runs: ``tables[r]`` pairs replicate r's cell A with its cell B on the same
    seeds; ``margin`` is δ, within which the two count as equivalent."""

    name: str
    tables: Mapping[int, PairedTable]
    margin: float

    def differences(self) -> np.ndarray:
        return np.array([t.effect for t in self.tables.values()], float)


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


@dataclasses.dataclass(frozen=True)
class ClaimResult:
    """One method claim decided at ``level`` (α/m in a family of m).

    Sign test: ``ahead``/``behind``: runs in which A's/B's score is the higher; ``share_low``/``share_high``:
    the interval for q (its estimand); ``p_value``: the exact two-sided sign test of q = ½. Mean: ``estimate``
    (the replicates' mean difference) and its betting interval ``low``/``high`` (None for an unbounded score).
    ``differing_runs_needed``: differing runs at which the sign test decides the claim with probability 0.8
    when A's run is the safer in 9 of 10 of them; ``equivalence_runs_needed``: runs at which Hoeffding's
    interval decides equivalence within ±δ with probability 0.8 at Δ = 0 whatever the spread (None where no
    bounded range). Both None once the claim is decided."""

    name: str
    estimate: float
    low: float | None
    high: float | None
    ahead: int
    behind: int
    share_low: float
    share_high: float
    p_value: float
    differing_runs_needed: int | None
    equivalence_runs_needed: int | None
    replicates: tuple[int, ...]
    level: float
    margin: float
    verdict: Verdict
    reason: Reason
    estimand: str
    assumption: str


def sign_runs_needed(level: float, power: float = POWER, share: float = PLANNED_SHARE) -> int:
    """Fewest differing runs m at which the exact two-sided sign test at ``level`` rejects on A's side with
    probability ≥ ``power`` when each differing run favours A with probability ``share`` (exact binomial sums)."""
    for m in range(1, 100_000):
        k = np.arange(m + 1)
        rejects = 2 * special.bdtrc(k - 1, m, 0.5) <= level  # P(X ≥ k) under ½, doubled
        if rejects.any():
            first = int(np.argmax(rejects))
            if special.bdtrc(first - 1, m, share) >= power:
                return m
    raise ValueError(f"no run count up to 100000 reaches power {power} at level {level}")


def equivalence_runs_needed(margin: float, level: float, power: float = POWER) -> int:
    """Fewest runs R at which Hoeffding's interval for a mean on [−1, 1] (half-width √(2 ln(2/level)/R)) lies
    inside (−δ, δ) with probability ≥ ``power`` when the mean is 0, whatever the distribution: Hoeffding bounds
    the sample mean's own excursion by √(2 ln(2/(1 − power))/R) with that probability."""
    total = math.sqrt(2 * math.log(2 / level)) + math.sqrt(2 * math.log(2 / (1 - power)))
    return math.floor((total / margin) ** 2) + 1


def _sign_side(differences: np.ndarray, level: float) -> tuple[int, int, float, float, float]:
    ahead, behind = int(np.sum(differences > 0)), int(np.sum(differences < 0))
    low, high = share_interval(ahead, ahead + behind, level)
    return ahead, behind, low, high, sign_test_p(ahead, ahead + behind)


def _verdict(share: tuple[float, float], mean: tuple[float, float] | None, margin: float) -> Verdict:
    if share[0] > 0.5:
        return Verdict.SUPPORTED
    if share[1] < 0.5:
        return Verdict.REFUTED
    if mean is not None and -margin < mean[0] and mean[1] < margin:
        return Verdict.EQUIVALENT
    return Verdict.UNDECIDED


def decide_claim(claim: MethodClaim | ScoreClaim, level: float) -> ClaimResult:
    bounded = isinstance(claim, MethodClaim)
    differences = claim.differences() if bounded else claim.per_replicate()
    replicates = tuple(claim.tables if bounded else claim.differences)
    ahead, behind, share_low, share_high, p = _sign_side(differences, level)
    mean = mean_interval(differences, -1.0, 1.0, level) if bounded else None
    ends = (float(mean.low), float(mean.high)) if mean is not None else None
    verdict = _verdict((share_low, share_high), ends, claim.margin)
    decided = verdict is not Verdict.UNDECIDED
    reason = Reason.DECIDED if decided else Reason.TOO_FEW_REPLICATES if len(replicates) < 2 else Reason.NOT_DECIDED
    return ClaimResult(
        claim.name,
        float(differences.mean()),
        None if ends is None else ends[0],
        None if ends is None else ends[1],
        ahead,
        behind,
        share_low,
        share_high,
        p,
        None if decided else sign_runs_needed(level),
        None if decided or not bounded else equivalence_runs_needed(claim.margin, level),
        replicates,
        float(level),
        float(claim.margin),
        verdict,
        reason,
        SIGN_ESTIMAND + ("; " + MEAN_ESTIMAND if bounded else ""),
        ASSUMPTION,
    )


def decide_claims(claims: Sequence[MethodClaim | ScoreClaim], alpha: float) -> list[ClaimResult]:
    """A family of method claims at family-wise error α: each at α/m (Bonferroni), so with probability ≥ 1 − α
    every SUPPORTED, REFUTED and EQUIVALENT verdict of the family is right, whatever the training runs do."""
    if not claims or any(not (c.tables if isinstance(c, MethodClaim) else c.differences) for c in claims):
        raise ValueError("method claims need at least one claim, each with at least one replicate's table")
    level = split_gamma(alpha, len(claims))
    return [decide_claim(c, level) for c in claims]
