"""Method-level claims: is method A (or its warnings) safer than B over the distribution of training runs?

The estimand is the mean over training runs, Δ = E[η_A,r − η_B,r]. Replicate r gives one paired difference
Δ̂_r = η̂_A,r − η̂_B,r from its two cells on the same rollout seeds (the heads share the replicate's trunk);
replicates are independent training runs driving disjoint seed blocks, so the R differences are independent.
Student's paired t across replicates decides a claim **under its assumption: the Δ̂_r are i.i.d. and
approximately normal**. Nothing checks that assumption; with 2–8 replicates nothing could. Two floors keep
the interval from collapsing where the replicates' differences happen to coincide (e.g. every cell 1.00):

- the variance used is at least the replicates' mean within-replicate variance of the paired difference,
  (d̂_r − Δ̂_r²) / n_r with d̂_r the discordant share — Var(Δ̂_r) can be no smaller, whatever the spread;
- the equivalence interval's variance is at least the mean of δ(1 − δ) / n_r: whenever |Δ| = δ,
  Var(Δ̂_r) = Var(Δ_r) + E[d_r − Δ_r²] / n_r ≥ (1 − 1/n_r) E[Δ_r²] + E|Δ_r| / n_r − δ² ≥ δ(1 − δ) / n_r,
  so at the equivalence margin no replicate set is as alike as "all 1.00" suggests.

A claim reads "A is safer than B" (Δ > 0). SUPPORTED: the interval lies above 0; REFUTED: below 0 (the claim
is false — B is the safer); EQUIVALENT: the equivalence interval lies inside (−δ, δ). Each verdict is wrong
only if the truth lies beyond one end of an interval containing the level-(1 − α) t-interval, an event of
probability ≤ α/2 under the assumption; `decide_claims` puts each of m claims at α/m (Bonferroni), so the union
bound covers every verdict of every claim at once. `tests/test_uq_claims.py` measures the error rates under
Beta-spread training runs: at most 0.025 per kind where the runs spread symmetrically or moderately. Where one
method's runs pile at 1 and rarely fail, the difference is skewed and the assumption fails: a false
EQUIVALENT at the margin then reaches 0.05–0.17 (mean rate 0.97, κ = 10 to 2), and with equal means but only
B's runs skewed, REFUTED reaches 0.35 (0.97, 100 rollouts, 8 replicates).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import optimize, special, stats

from uqdrive.uq.bounds import check_unit
from uqdrive.uq.multiplicity import split_gamma
from uqdrive.uq.paired import PairedTable
from uqdrive.uq.verdict import Reason, Verdict

ASSUMPTION = "the replicates' paired differences are i.i.d. and approximately normal (Student's t)"
POWER = 0.8


@dataclasses.dataclass(frozen=True)
class ReplicateT:
    """Student's paired t over the last axis (replicates) of counts shaped [..., R]; every field shaped [...].

    ``sd``: the floored sd of one replicate's difference; ``low``, ``high``: the two-sided interval at level
    1 − ``level``, clipped to [−1, 1]; ``equivalence_low``, ``equivalence_high``: the same with the variance also
    floored at the margin's; ``p_value``: two-sided, for "Δ = 0" (1 where the estimate and the variance are 0).
    Fewer than two replicates: the interval is [−1, 1] and p is 1.
    """

    estimate: np.ndarray
    sd: np.ndarray
    low: np.ndarray
    high: np.ndarray
    equivalence_low: np.ndarray
    equivalence_high: np.ndarray
    p_value: np.ndarray


def replicate_t(a_only: np.ndarray, b_only: np.ndarray, pairs: np.ndarray, level: float, margin: float) -> ReplicateT:
    """The paired t across replicates from each replicate's paired table (counts and pairs shaped [..., R])."""
    level, margin = check_unit("level", level), check_unit("margin", margin)
    a, b = np.asarray(a_only, float), np.asarray(b_only, float)
    n = np.broadcast_to(np.asarray(pairs, float), a.shape)
    effects = (a - b) / n
    within = ((a + b) / n - effects**2) / n
    return _paired_t(effects, within, margin * (1 - margin) / n, level, bound=1.0)


def replicate_t_means(differences: Sequence[np.ndarray], level: float) -> ReplicateT:
    """The paired t across replicates of a continuous per-run difference (e.g. the margin of A's run i minus B's):
    replicate r contributes the mean of its runs' differences; its within-replicate variance (sample variance / n)
    floors the variance as for counts. No margin floor is proven for an unbounded difference: the equivalence
    interval is the interval itself."""
    level = check_unit("level", level)
    runs = [np.asarray(d, float) for d in differences]
    if any(d.ndim != 1 or d.size < 2 or not np.isfinite(d).all() for d in runs):
        raise ValueError("each replicate needs at least two finite paired differences")
    effects = np.array([d.mean() for d in runs])
    within = np.array([d.var(ddof=1) / d.size for d in runs])
    return _paired_t(effects, within, np.zeros_like(within), level, bound=math.inf)


def _paired_t(effects: np.ndarray, within: np.ndarray, margin_floor: np.ndarray, level: float, bound: float):
    """Student's t over the last axis of per-replicate ``effects``, the variance floored at the mean ``within``
    variance (the equivalence interval's also at the mean ``margin_floor``), intervals clipped to ±``bound``."""
    estimate, count = effects.mean(-1), effects.shape[-1]
    if count < 2:
        whole = np.full_like(estimate, bound)
        return ReplicateT(
            estimate, np.full_like(estimate, np.inf), -whole, whole, -whole, whole, np.ones_like(estimate)
        )
    variance = np.maximum(effects.var(-1, ddof=1), within.mean(-1))
    margin_variance = np.maximum(variance, margin_floor.mean(-1))
    quantile = special.stdtrit(count - 1, 1 - level / 2)
    half, margin_half = (quantile * np.sqrt(v / count) for v in (variance, margin_variance))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.abs(estimate) / np.sqrt(variance / count)
    p = np.where(variance > 0, 2 * special.stdtr(count - 1, -t), np.where(estimate == 0, 1.0, 0.0))
    return ReplicateT(
        estimate,
        np.sqrt(variance),
        np.clip(estimate - half, -bound, bound),
        np.clip(estimate + half, -bound, bound),
        np.clip(estimate - margin_half, -bound, bound),
        np.clip(estimate + margin_half, -bound, bound),
        p,
    )


def claim_verdicts(result: ReplicateT, margin: float) -> np.ndarray:
    """The verdict of the claim "A safer than B" (Δ > 0) from each interval, as an array of `Verdict` values.

    SUPPORTED: the interval lies above 0; REFUTED: below 0; EQUIVALENT: the equivalence interval lies inside
    (−δ, δ), i.e. both one-sided tests of |Δ| ≥ δ reject at level/2 each; else UNDECIDED.
    """
    above, below = result.low > 0, result.high < 0
    within = (result.equivalence_low > -margin) & (result.equivalence_high < margin)
    choices = [Verdict.SUPPORTED, Verdict.REFUTED, Verdict.EQUIVALENT]
    return np.select([above, below, within], choices, Verdict.UNDECIDED).astype(object)


def _power(noncentrality: float, freedom: int, critical: float) -> float:
    """P(the t statistic passes the critical value on the difference's own side), noncentral t."""
    return float(stats.nct.sf(critical, freedom, noncentrality))


def detectable_difference(sd: float, replicates: int, level: float, power: float = POWER) -> float:
    """Smallest |Δ| the two-sided paired t at ``level`` detects (rejects on Δ's side) with probability ``power``
    from ``replicates`` replicates whose differences have standard deviation ``sd`` (noncentral t; inf below two
    replicates)."""
    level, power = check_unit("level", level), check_unit("power", power)
    if replicates < 2 or not math.isfinite(sd):
        return math.inf
    if sd <= 0:
        return 0.0
    freedom, critical = replicates - 1, float(special.stdtrit(replicates - 1, 1 - level / 2))
    high = critical + 1.0
    while _power(high, freedom, critical) < power:
        high *= 2
    noncentrality = optimize.brentq(lambda x: _power(x, freedom, critical) - power, 0.0, high, xtol=1e-10)
    return float(noncentrality * sd / math.sqrt(replicates))


def replicates_needed(sd: float, difference: float, level: float, power: float = POWER) -> int:
    """Fewest replicates (≥ 2) at which `detectable_difference` is at most ``difference``."""
    if difference <= 0:
        raise ValueError(f"the difference to detect must be positive, got {difference!r}")

    def detects(count: int) -> bool:
        return detectable_difference(sd, count, level, power) <= difference

    low, high = 1, 2  # detects(low) is False (one replicate detects nothing); find a high that detects
    while not detects(high):
        low, high = high, high * 2
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (low, middle) if detects(middle) else (middle, high)
    return high


@dataclasses.dataclass(frozen=True)
class MethodClaim:
    """ "A is safer than B" over training runs: ``tables[r]`` pairs replicate r's cell A with its cell B on the same
    seeds; ``margin`` is δ, within which the two count as equivalent."""

    name: str
    tables: Mapping[int, PairedTable]
    margin: float


@dataclasses.dataclass(frozen=True)
class MarginClaim:
    """ "A keeps a larger margin than B" over training runs (a continuous estimand, not η1): ``differences[r]``:
    replicate r's per-run margin of A minus B's on the same seeds; ``margin``: δ, in the differences' units."""

    name: str
    differences: Mapping[int, np.ndarray]
    margin: float


@dataclasses.dataclass(frozen=True)
class ClaimResult:
    """One method claim decided at ``level`` (α/m in a family of m): the estimate of Δ, its interval and the
    equivalence interval, the p-value, the verdict and, where undecided, the reason; ``detectable``: the |Δ| a
    design of this many replicates with this sd detects with 80 % power at this level; ``needed``: the
    replicates that would detect a difference of δ so (None below two replicates: no sd to plan from)."""

    name: str
    estimate: float
    low: float
    high: float
    equivalence_low: float
    equivalence_high: float
    p_value: float
    sd: float
    detectable: float
    needed: int | None
    replicates: tuple[int, ...]
    level: float
    margin: float
    verdict: Verdict
    reason: Reason
    assumption: str


def decide_claim(claim: MethodClaim | MarginClaim, level: float) -> ClaimResult:
    if isinstance(claim, MarginClaim):
        replicates = tuple(claim.differences)
        result = replicate_t_means(list(claim.differences.values()), level)
    else:
        replicates = tuple(claim.tables)
        counts = np.array([[t.a_only, t.b_only, t.n] for t in claim.tables.values()], float).reshape(-1, 3)
        result = replicate_t(counts[:, 0], counts[:, 1], counts[:, 2], level, claim.margin)
    verdict = Verdict(claim_verdicts(result, claim.margin).item())
    reason = Reason.DECIDED
    if verdict is Verdict.UNDECIDED:
        reason = Reason.TOO_FEW_REPLICATES if len(replicates) < 2 else Reason.INTERVAL_TOO_WIDE
    fields = ("estimate", "low", "high", "equivalence_low", "equivalence_high", "p_value", "sd")
    values = {f: float(getattr(result, f)) for f in fields}
    detectable = detectable_difference(values["sd"], len(replicates), level)
    needed = replicates_needed(values["sd"], claim.margin, level) if len(replicates) >= 2 else None
    return ClaimResult(
        claim.name,
        **values,
        detectable=detectable,
        needed=needed,
        replicates=replicates,
        level=float(level),
        margin=float(claim.margin),
        verdict=verdict,
        reason=reason,
        assumption=ASSUMPTION,
    )


def decide_claims(claims: Sequence[MethodClaim | MarginClaim], alpha: float) -> list[ClaimResult]:
    """A family of method claims at family-wise error α: each at α/m (Bonferroni), so with probability ≥ 1 − α
    (under the t assumption) every SUPPORTED, REFUTED and EQUIVALENT verdict of the family is right."""
    if not claims or any(not (c.differences if isinstance(c, MarginClaim) else c.tables) for c in claims):
        raise ValueError("method claims need at least one claim, each with at least one replicate's table")
    level = split_gamma(alpha, len(claims))
    return [decide_claim(c, level) for c in claims]
