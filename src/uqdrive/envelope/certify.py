"""Phase two of an envelope: each region's η1 — of a rollout at a condition drawn uniformly in the region, on a
fresh seed — certified against the target τ by the sequential threshold test (`uqdrive.uq.threshold`, unforced),
at the region's share γ_r of the family-wise γ.

Each region ends safe (η1 ≥ τ certified), unsafe (η1 < τ certified) or undecided (its budget spent). A region's
test wrongly certifies with probability ≤ γ_r whatever its η1; the partition is fixed before any of these
rollouts (by phase one's), so by the union bound every verdict of the map holds at once with probability
≥ 1 − Σ γ_r ≥ 1 − γ.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from uqdrive.envelope.partition import Region
from uqdrive.envelope.search import BoundaryModel
from uqdrive.schema import Count, OpenUnit, Unit, invalid, schema
from uqdrive.uq import clopper_pearson_n
from uqdrive.uq.estimators import Draw
from uqdrive.uq.multiplicity import split_gamma
from uqdrive.uq.threshold import ThresholdTest


class RegionVerdict(StrEnum):
    """A region's verdict: its η1 (over conditions drawn uniformly in it) certified above τ, below it, or neither."""

    SAFE = "safe"
    UNSAFE = "unsafe"
    UNDECIDED = "undecided"


_VERDICTS: dict[str | None, RegionVerdict] = {
    "above": RegionVerdict.SAFE,
    "below": RegionVerdict.UNSAFE,
    None: RegionVerdict.UNDECIDED,
}


@schema(frozen=True)
class CertifySettings:
    """The target and the guarantee: each region's η1 against ``threshold`` (τ), the whole map right with
    probability ≥ 1 − ``gamma``; a region's test looks after every ``look_size`` rollouts and stops undecided after
    ``region_budget``, and phase two stops after ``certify_budget`` rollouts in all (the regions left undecided,
    said so). ``theta``: the test's indifference half-width (0: "safe" certifies η1 ≥ τ and "unsafe"
    η1 < τ; θ > 0 stops sooner but certifies only η1 > τ − θ and η1 < τ + θ). ``grid_theta``: the half-width of
    the per-cell interval of the grid the map's cost is compared with."""

    threshold: OpenUnit = 0.9
    gamma: OpenUnit = 0.05
    theta: Unit = 0.0
    look_size: Count = 4
    region_budget: Count = 64
    certify_budget: Count | None = None
    grid_theta: OpenUnit = 0.05

    def __post_init__(self) -> None:
        if self.region_budget < self.look_size:
            raise invalid("region_budget", self.region_budget, f"must be >= look_size ({self.look_size})")
        if not self.theta < min(self.threshold, 1 - self.threshold):
            raise invalid(
                "theta",
                self.theta,
                f"must be < min(threshold, 1 - threshold) = {min(self.threshold, 1 - self.threshold):g}",
            )

    @property
    def looks(self) -> tuple[int, ...]:
        """Rollout counts at which a region's test looks: every look_size, and the budget."""
        return tuple(sorted({*range(self.look_size, self.region_budget + 1, self.look_size), self.region_budget}))


@dataclass(frozen=True)
class Decision:
    """How a region's test ended: its verdict, the rollouts it ran and how many of them were safe."""

    verdict: RegionVerdict
    rollouts: int
    safe: int


@dataclass(frozen=True)
class RegionResult:
    region: Region
    gamma: float
    verdict: RegionVerdict
    rollouts: int
    safe: int

    @property
    def eta1_hat(self) -> float:
        return self.safe / self.rollouts if self.rollouts else float("nan")


def region_test(settings: CertifySettings, gamma: float) -> ThresholdTest:
    """A region's test at its share γ_r: unforced, so a region it cannot decide within its budget stays undecided."""
    return ThresholdTest(settings.threshold, gamma, settings.looks, theta=settings.theta, forced=False)


def threshold_decision(settings: CertifySettings, gamma: float, draw: Draw, cap: int | None = None) -> Decision:
    """A region's test on its outcomes ``draw(count)``, look by look: safe (η1 ≥ τ certified), unsafe (η1 < τ), or
    undecided after the region's budget or ``cap`` rollouts, whichever comes first. Ended early by a cap, it is the
    same test stopped sooner: undecided more often, never wrong more often."""
    test = region_test(settings, gamma)
    k = n = 0
    for look in test.looks:
        if cap is not None and look > cap:
            break
        k, n = k + int(np.asarray(draw(look - n)).sum()), look
        decision = test.decide(k, n)
        if decision is not None:
            return Decision(_VERDICTS[decision], n, k)
    return Decision(RegionVerdict.UNDECIDED, n, k)


def clean_run_to_safe(settings: CertifySettings, gamma: float) -> int | None:
    """The fewest rollouts, all safe, after which a region's test at γ_r certifies safe; None: never within the
    region's budget."""
    test = region_test(settings, gamma)
    return next((n for n in test.looks if test.decide(n, n) == "above"), None)


def decision_order(regions: Sequence[Region], model: BoundaryModel, settings: CertifySettings) -> list[int]:
    """The regions by the decisions their tests are expected to make per rollout, most first, if each region's
    η1 were phase one's estimate of it (the kernel-smoothed rate, averaged over the region): P(safe or unsafe)
    over the expected rollouts, both exact for the test. A total budget then goes to the regions it can decide
    cheaply (clearly unsafe ones in a few rollouts, safe ones in a clean run) before the boundary's."""
    shares = (split_gamma(settings.gamma, len(regions)),) * len(regions)

    def rate(i: int) -> float:
        eta = float(np.mean(model.rate(regions[i].grid(2))))
        above, below, draws = region_test(settings, shares[i]).operating_characteristics(eta)
        return float((above[0] + below[0]) / draws[0])

    return sorted(range(len(regions)), key=lambda i: -rate(i))


def certify(
    regions: Sequence[Region],
    gamma: float,
    decide: Callable[[int, Region, float, int | None], Decision],
    order: Sequence[int] | None = None,
    budget: int | None = None,
    first_look: int = 1,
) -> list[RegionResult]:
    """``decide(i, region, γ_r, cap)``: region i's test on its own outcomes at error γ_r, at most ``cap`` rollouts
    (None: no cap), γ split equally (`split_gamma`). Regions go in ``order`` (default: as given) while phase two's
    ``budget`` (None: no total budget) lasts; one reached with fewer than ``first_look`` rollouts left is undecided
    without any."""
    shares = (split_gamma(gamma, len(regions)),) * len(regions)
    left = budget
    decisions: dict[int, Decision] = {}
    for i in range(len(regions)) if order is None else order:
        if left is not None and left < first_look:
            decisions[i] = Decision(RegionVerdict.UNDECIDED, 0, 0)
            continue
        decisions[i] = decide(i, regions[i], shares[i], left)
        left = None if left is None else left - decisions[i].rollouts
    return [
        RegionResult(region, share, decisions[i].verdict, decisions[i].rollouts, decisions[i].safe)
        for i, (region, share) in enumerate(zip(regions, shares))
    ]


def grid_cost(dim: int, depth: int, theta: float, gamma: float) -> dict[str, float | int]:
    """What the same map would cost as a grid at the partition's finest resolution (2^depth cells an axis) with a
    per-cell interval: a fixed-n exact (Clopper–Pearson) interval of half-width θ in every cell (the scheme a
    safety sweep uses per cell), family-wise at γ like the map (each cell at γ / cells), and, beside it, each
    cell at γ alone (no guarantee for the map as a whole)."""
    cells = 2 ** (depth * dim)
    share = split_gamma(gamma, cells)
    per_cell = clopper_pearson_n(theta, share)
    return {
        "cells": cells,
        "gamma_per_cell": share,
        "per_cell": per_cell,
        "rollouts": cells * per_cell,
        "rollouts_per_cell_gamma": cells * clopper_pearson_n(theta, gamma),
    }
