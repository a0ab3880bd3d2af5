"""Rare events over an operating domain: refute "η1 ≥ target" by importance sampling with a bound valid at any
stopping time, or certify it at the black-box floor. The estimand is η1 over the domain — a rollout's condition
drawn from the domain's density — never a cell's η1; p = 1 − η1 is its failure probability.

Refutation (H0: p ≤ m, m = 1 − target). Round r draws its conditions from the defensive mixture
q_r = λ·nominal + (1 − λ)·g_r, g_r adapted toward failure by a cross-entropy step on the rollouts' margins
(`uqdrive.uq.rare_proposal`) from earlier rounds only. Then X_i = w_i·1{fail_i} with w_i = nominal/q_r ≤ 1/λ
has E[X_i | past] = p exactly (q_r > 0 wherever the nominal is), whatever the proposal. The capital
K_t = Π (1 + s_i (X_i − m)), s_i ∈ [0, c/m] fixed before X_i, is a nonnegative supermartingale under H0
(each factor ≥ 1 − c > 0 and has conditional mean 1 + s_i (p − m) ≤ 1), so by Ville's inequality
P(K_t ≥ 1/γ at any t) ≤ γ: rejecting at the first look where it does is valid at any data-dependent stopping
time, every rollout being a look. Inverted over a grid of m (all grid values up to L rejected) it is a lower
confidence sequence L_t for p. This is the betting construction of `uqdrive.uq.betting`, one-sided; its
stakes do not fit here: they are sized for means of order ½ (≈ √(2 ln(2/α)/(σ²·i·ln i))), while X is 0 on
most rollouts and of order m ≈ 10⁻⁴ otherwise, so a stake worth betting is of order 1/m. The stake used is
half the Kelly stake of a two-point law fitted to the past (share of X > 0, their mean): for Bernoulli X it is
the exact Kelly stake; validity never depends on it, only speed does.

Certification: "η1 ≥ target" by the project's exact sequential threshold test (`uqdrive.uq.threshold`,
unforced, θ = 0) on rollouts drawn from the domain itself; with zero failures it needs n with target^n ≤ γ,
n ≥ ln(1/γ)/ln(1/target) (≈ ln(1/γ)/ε for small ε = 1 − target, but not bounded below by it), and no
black-box procedure can need fewer in expectation (docs/rare.md); its later looks make it 1.2 × that.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Protocol

import numpy as np
from pydantic import Field, Strict

from uqdrive.schema import Count, OpenUnit, invalid, schema
from uqdrive.uq.betting import CAP, mean_interval
from uqdrive.uq.rare_proposal import BetaMixture, ProductBeta, check_support, mixture_sample
from uqdrive.uq.threshold import ThresholdDecision, ThresholdTest

Defensive = Annotated[float, Strict(), Field(gt=0, le=1)]
Rollouts = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``world(points [runs, n, d], seeds [runs, n]) -> (failed [runs, n] bool, margins [runs, n])``: one rollout at
each condition (a point of the unit cube) on its seed; a margin ≤ 0 where it failed. A world may say what its
margin is (attribute ``margin``); ``"constant"`` is refused before any rollout when the proposal is to adapt."""
RUN_STRIDE = 1_000_000  # run r's rollout i drives seed base + r·1,000,000 + i, as a replicate's do
LOOK_FIRST, LOOK_GROWTH = 1.2, 1.5  # certification looks: 1.2 × the zero-failure floor, then ×1.5 up to the budget
# Later looks (certifying with a failure or two) take their share of γ, so zero failures no longer certify at the
# floor itself. Measured at target 0.999 (floor 2,995, budget 12,000; first look × growth → zero-failure cost /
# floor): 1 × 1.1 → 1.33, 1 × 1.5 → 1.50, 1.1 × 1.25 → 1.38, 1.2 × 1.5 → 1.20, all with P(certify) 0.87 at
# p = ε/3; a single look at the floor costs exactly the floor and cannot certify after any failure.


def floor_rollouts(target: float, gamma: float) -> int:
    """The fewest rollouts certifying η1 ≥ target at γ even with zero failures: the least n with target^n ≤ γ."""
    return math.ceil(math.log(gamma) / math.log(target) - 1e-9)


def refutation_floor(target: float, gamma: float, defensive: float) -> int:
    """The fewest rollouts any run of `refute` can refute "η1 ≥ target" in: the first failure only sets the stake
    (none is bet before a failure has been seen), and each later rollout multiplies the capital by at most
    1 + (c/m)(1/λ − m) (X ≤ 1/λ, stake ≤ c/m), which must reach 1/γ."""
    m = 1.0 - target
    growth = math.log1p(CAP / m * (1.0 / defensive - m))
    return 1 + math.ceil(math.log(1 / gamma) / growth - 1e-12)


@schema(frozen=True)
class RareSettings:
    """Refute or certify "η1 ≥ ``target`` over the domain" at error ≤ ``gamma``. Refutation: rounds of
    ``round_size`` rollouts from λ = ``defensive`` × nominal + (1 − λ) × proposal, up to ``refute_budget``; the
    proposal's cross-entropy step keeps the ``elite`` share of lowest margins among the last ``memory`` rounds and
    blends the fit by ``smoothing``; ``components`` > 1 makes the proposal a mixture of that many products of
    Betas, one per failure mode it finds (`rare_proposal.mixture_step`; smoothing must then be 1). Certification:
    at most ``certify_budget`` rollouts from the domain."""

    target: OpenUnit = 0.9999
    gamma: OpenUnit = 0.05
    defensive: Defensive = 0.1
    refute_budget: Count = 5_000
    round_size: Count = 10
    elite: OpenUnit = 0.1
    smoothing: Defensive = 1.0
    memory: Count = 5
    components: Count = 1
    certify_budget: Count = 100_000

    def __post_init__(self) -> None:
        if self.components > 1 and self.smoothing != 1:
            raise invalid(
                "smoothing",
                self.smoothing,
                f"must be 1 with components={self.components} (a mixture's components "
                "are found afresh each step, so there is no earlier one to blend with)",
            )
        least = refutation_floor(self.target, self.gamma, self.defensive)
        if self.refute_budget < least:
            raise invalid(
                "refute_budget",
                self.refute_budget,
                f"no run can refute eta1 >= {self.target} at gamma={self.gamma} with defensive={self.defensive} "
                f"in fewer than {least} rollouts (the first failure sets the stake, each later one multiplies the "
                f"capital by at most 1 + 0.75/m (1/defensive - m)): raise refute_budget to {least} or more",
            )
        need = floor_rollouts(self.target, self.gamma)
        if self.certify_budget < need:
            raise invalid(
                "certify_budget",
                self.certify_budget,
                f"cannot certify eta1 >= {self.target} at gamma={self.gamma} even with zero failures: that needs "
                f"{need} rollouts (the least n with target^n <= gamma: ln(1/gamma)/ln(1/target) rounded up)",
            )

    @property
    def null(self) -> float:
        """m = 1 − target: the failure probability H0 allows."""
        return 1.0 - self.target


class Evidence(Protocol):
    """A sequential test of H0: p ≤ m fed one round at a time, the observations in their order."""

    def observe(self, x: np.ndarray) -> np.ndarray:
        """x [runs, n]: per run, the index in this round of the first look rejecting H0, −1 where none did."""
        ...


class BettingEvidence:
    """The capital K_t(m) per run (``null``: m per run, [runs]) and its crossing of 1/γ (see the module)."""

    def __init__(self, null: np.ndarray, gamma: float) -> None:
        self.null = np.asarray(null, float)
        self.threshold = math.log(1 / gamma)
        self.count = 0
        self.total = np.zeros(self.null.shape)
        self.positives = np.zeros(self.null.shape)
        self.log_capital = np.zeros(self.null.shape)

    def _stakes(self, x: np.ndarray) -> np.ndarray:
        """Half the two-point Kelly stake from the observations before each one, capped at c/m."""
        seen = self.count + np.arange(x.shape[1])
        total = self.total[:, None] + np.cumsum(x, 1) - x
        positives = self.positives[:, None] + np.cumsum(x > 0, 1) - (x > 0)
        m = self.null[:, None]
        mean, positive_mean = total / (seen + 1), total / np.maximum(positives, 1)
        bet = (mean > m) & (positive_mean > m)
        with np.errstate(divide="ignore", invalid="ignore"):
            kelly = np.where(bet, (mean - m) / (m * (positive_mean - m)), 0.0)
        return np.clip(0.5 * kelly, 0.0, CAP / m)

    def observe(self, x: np.ndarray) -> np.ndarray:
        path = self.log_capital[:, None] + np.cumsum(np.log1p(self._stakes(x) * (x - self.null[:, None])), 1)
        crossed = path >= self.threshold
        self.count += x.shape[1]
        self.total += x.sum(1)
        self.positives += (x > 0).sum(1)
        self.log_capital = path[:, -1]
        return np.where(crossed.any(1), crossed.argmax(1), -1)


@dataclass(frozen=True)
class FailureRecord:
    """A failed rollout, for replay: its run, seed, condition (a point of the unit cube), weight and margin."""

    run: int
    seed: int
    point: tuple[float, ...]
    weight: float
    margin: float


@dataclass(frozen=True)
class Refutation:
    """Per run: ``refuted`` (η1 < target shown), ``rollouts`` spent (to the refutation, else the budget),
    ``failures`` seen in them and ``observations`` X_i (0 past the stop); ``records``: the failures of the runs
    asked for. Error: P(refuted | η1 ≥ target) ≤ ``gamma``."""

    target: float
    gamma: float
    refuted: np.ndarray
    rollouts: np.ndarray
    failures: np.ndarray
    observations: np.ndarray
    records: tuple[FailureRecord, ...]


def _records(run_ids, seeds, points, weights, margins, failed) -> list[FailureRecord]:
    r, i = np.nonzero(failed)
    return [
        FailureRecord(
            int(run_ids[a]),
            int(seeds[a, b]),
            tuple(map(float, points[a, b])),
            float(weights[a, b]),
            float(margins[a, b]),
        )
        for a, b in zip(r, i)
    ]


def refute(
    world: Rollouts,
    nominal: ProductBeta,
    settings: RareSettings,
    rng: np.random.Generator,
    *,
    runs: int = 1,
    proposal: ProductBeta | None = None,
    adapt: bool = True,
    seed: int = 0,
    evidence: Evidence | None = None,
    names: tuple[str, ...] | None = None,
    record_runs: int = 1,
) -> Refutation:
    """Refute "η1 ≥ target" in ``runs`` independent runs (vectorised), each stopping at its first rejection or
    at the budget. ``proposal``: the first proposal (default: the nominal); ``adapt``: cross-entropy steps
    between rounds; ``evidence``: the test (default: betting). Checks the support before any rollout."""
    proposal = nominal if proposal is None else proposal
    check_support(nominal, proposal, names or tuple(f"axes[{j}]" for j in range(nominal.dim)))
    if adapt and getattr(world, "margin", None) == "constant":
        raise ValueError(
            "world.margin=constant: the cross-entropy step has nothing to adapt on; feed a margin that varies "
            "(a lane rule's, or +-1 by the outcome) or run plain Monte Carlo (defensive=1, adapt off)"
        )
    evidence = evidence or BettingEvidence(np.full(runs, settings.null), settings.gamma)
    k, budget = settings.components, settings.refute_budget
    law = proposal.runs(runs) if k == 1 else BetaMixture.copies(proposal, k, runs)
    stop, spent, history = np.full(runs, -1), 0, []  # history: the last rounds the cross-entropy step fits on
    observations, failures, records = np.zeros((runs, budget)), np.zeros(runs, int), []
    while spent < budget and (stop < 0).any():
        n = min(settings.round_size, budget - spent)
        points, weights = mixture_sample(nominal, law, settings.defensive, rng, runs, n)
        seeds = seed + np.arange(runs)[:, None] * RUN_STRIDE + spent + np.arange(n)
        failed, margins = world(points, seeds)
        x = weights * failed
        first = evidence.observe(x)
        counted = (stop[:, None] < 0) & ((first[:, None] < 0) | (np.arange(n) <= first[:, None]))
        newly = (stop < 0) & (first >= 0)
        stop[newly] = spent + first[newly] + 1
        observations[:, spent : spent + n] = x * counted
        failures += (failed & counted).sum(1)
        keep = min(record_runs, runs)
        records += _records(np.arange(keep), seeds, points, weights, margins, (failed & counted)[:keep])
        spent += n
        if adapt:
            history = [*history[1 - settings.memory :], (points, margins, weights)] if settings.memory > 1 else []
            seen = [np.concatenate(part, 1) for part in zip(*history)] or [points, margins, weights]
            law = law.step(*seen, settings.elite, settings.smoothing)
    refuted = stop >= 0
    rollouts = np.where(refuted, stop, spent)
    return Refutation(settings.target, settings.gamma, refuted, rollouts, failures, observations, tuple(records))


def failure_lower_bound(observations: np.ndarray, gamma: float, grid: np.ndarray | None = None) -> float:
    """A lower confidence bound for p from one run's X_1 … X_t (in order, valid at any t): the largest grid
    value m such that every grid value up to it had its capital cross 1/γ by t (0 if the first did not). Only
    the test at the least grid value ≥ p can err, so the bound exceeds p with probability ≤ γ."""
    grid = np.geomspace(1e-9, 1.0, 241) if grid is None else np.sort(np.asarray(grid, float))
    x = np.broadcast_to(np.asarray(observations, float), (grid.size, np.size(observations)))
    test = BettingEvidence(grid, gamma)
    crossed = test.observe(x) >= 0
    below = np.cumprod(crossed).astype(bool)
    return float(grid[below][-1]) if below.any() else 0.0


@dataclass(frozen=True)
class FailureEstimate:
    """The importance-sampled estimate p̂ = mean of X_i over a run's rollouts, with two two-sided betting intervals
    at level 1 − γ (`uqdrive.uq.betting`; by Ville's inequality valid at the run's data-dependent stopping time,
    tested by simulation at a fixed number of rollouts): ``interval`` on
    X ∈ [0, 1/λ], valid without assumption and wide; ``if_dominant`` on X ∈ [0, 1], valid only if every round's
    mixture dominates the nominal density where the car fails (then every failure's weight is ≤ 1) — None where a
    failure's weight above 1 shows that it did not. Neither is a certification: that is `certify`'s."""

    estimate: float
    interval: tuple[float, float]
    if_dominant: tuple[float, float] | None


def failure_estimate(observations: np.ndarray, defensive: float, gamma: float) -> FailureEstimate:
    """p̂ and its intervals from one run's X_1 … X_t (in order; every weight ≤ 1/``defensive``)."""
    x = np.asarray(observations, float)
    anywhere = mean_interval(x, 0.0, 1.0 / defensive, gamma)
    dominated = None
    if x.max(initial=0.0) <= 1.0:
        inside = mean_interval(x, 0.0, 1.0, gamma)
        dominated = (float(inside.low), float(inside.high))
    return FailureEstimate(float(x.mean()), (float(anywhere.low), float(anywhere.high)), dominated)


def certification_test(settings: RareSettings) -> ThresholdTest:
    """The exact sequential test certifying η1 ≥ target (unforced, θ = 0), looking first at 1.2 × the zero-failure
    floor and then ×1.5 up to the certification budget (before the floor no count can certify)."""
    looks, n = [], math.ceil(LOOK_FIRST * floor_rollouts(settings.target, settings.gamma))
    while n < settings.certify_budget:
        looks.append(n)
        n = math.ceil(n * LOOK_GROWTH)
    looks.append(settings.certify_budget)
    return ThresholdTest(settings.target, settings.gamma, tuple(looks), theta=0.0, forced=False)


def zero_failure_rollouts(test: ThresholdTest) -> int | None:
    """The rollouts the test needs to certify "above" when none fails (None: the budget cannot)."""
    return next((n for n in test.looks if test.decide(n, n) == "above"), None)


def certify(draw: Callable[[int], np.ndarray], settings: RareSettings) -> ThresholdDecision:
    """Certify (``above``) or refute (``below``) η1 ≥ target from ``draw(m)``: m outcomes (1 safe, 0 failed) of
    rollouts whose conditions are drawn from the domain's density itself; None: undecided at the budget."""
    return certification_test(settings).run(draw)
