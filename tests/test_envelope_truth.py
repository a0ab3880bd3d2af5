"""The envelope against a known truth: a synthetic controller whose η1 at each condition is a known function, so a
map (search, partition, certification: the stage's own functions) costs milliseconds and every verdict can be
checked against the exact η1 of its region.

The truth is η1(u) = f0(u0) · f1(u1) with f a ramp (1, then falling linearly, clipped at 0), so a region's η1
(the mean over the region) and its lowest point are exact. Error rates over repeated maps are judged by their
own Clopper–Pearson interval, which must lie below the target.
"""

from dataclasses import dataclass

import numpy as np

from uqdrive.envelope.certify import CertifySettings, RegionResult, certify, threshold_decision
from uqdrive.envelope.partition import PartitionSettings, Region, partition
from uqdrive.envelope.search import SearchSettings, search
from uqdrive.uq import clopper_pearson_interval

TAU = 0.9


@dataclass(frozen=True)
class Ramp:
    """1 up to ``start``, then falling with ``slope`` (clipped at 0)."""

    start: float
    slope: float

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return np.clip(1 - self.slope * np.maximum(np.asarray(x) - self.start, 0), 0, 1)

    def integral(self, x: float) -> float:
        """∫_0^x of the ramp, exactly."""
        end = self.start + 1 / self.slope
        if x <= self.start:
            return x
        y = min(x, end) - self.start
        return self.start + y - self.slope * y * y / 2

    def mean(self, low: float, high: float) -> float:
        return (self.integral(high) - self.integral(low)) / (high - low)


@dataclass(frozen=True)
class Truth:
    ramps: tuple[Ramp, Ramp]

    def __call__(self, u: np.ndarray) -> np.ndarray:
        return self.ramps[0](u[:, 0]) * self.ramps[1](u[:, 1])

    def region_mean(self, r: Region) -> float:
        return self.ramps[0].mean(r.low[0], r.high[0]) * self.ramps[1].mean(r.low[1], r.high[1])

    def region_min(self, r: Region) -> float:  # both ramps fall, so the far corner is the lowest point
        return float(self(np.array([r.high]))[0])


GENTLE = Truth((Ramp(0.2, 0.8), Ramp(0.5, 0.5)))  # η1 falls by at most 0.16 across a region 1/8 wide


def make_map(
    truth: Truth,
    rng: np.random.Generator,
    search_settings: SearchSettings,
    partition_settings: PartitionSettings,
    settings: CertifySettings,
) -> list[RegionResult]:
    """One map of the synthetic controller: rollout outcomes are Bernoulli(η1(u)) at the conditions asked for."""

    def run(points: np.ndarray) -> np.ndarray:
        return (rng.random(len(points)) < truth(points)).astype(int)

    found = search(run, 2, settings.threshold, search_settings)
    regions = partition(found.model(settings.threshold, search_settings.bandwidth), 2, partition_settings)

    def decide(index: int, region: Region, gamma: float, cap: int | None):
        return threshold_decision(settings, gamma, lambda count: run(region.at(rng.random((count, 2)))), cap)

    return certify(regions, settings.gamma, decide)


def upper(errors: int, maps: int, confidence: float = 0.99) -> float:
    return float(clopper_pearson_interval(errors, maps, 1 - confidence)[1])


def test_the_map_is_right_everywhere_at_once_and_safe_regions_hold_no_condition_below_tau_minus_theta():
    """Family-wise: no region certified on the wrong side of τ (its η1 is the region's mean) in more than γ of the
    maps; pointwise, as the finest regions are narrow against the truth's slope: no condition with η1 < τ − θ
    inside a region certified safe."""
    gamma, theta, maps = 0.1, 0.1, 100
    settings = CertifySettings(threshold=TAU, gamma=gamma, look_size=8, region_budget=128)
    search_settings = SearchSettings(budget=64, initial=16, batch=8, bandwidth=0.1)
    rng = np.random.default_rng(2024)
    wrong = below = safe_maps = 0
    for _ in range(maps):
        results = make_map(GENTLE, rng, search_settings, PartitionSettings(min_depth=1, max_depth=3), settings)
        means = [GENTLE.region_mean(r.region) for r in results]
        wrong += any(
            (r.verdict == "safe" and m < TAU) or (r.verdict == "unsafe" and m >= TAU) for r, m in zip(results, means)
        )
        safe = [r for r in results if r.verdict == "safe"]
        below += any(GENTLE.region_min(r.region) < TAU - theta for r in safe)
        safe_maps += bool(safe) and any(r.verdict == "unsafe" for r in results)
    assert upper(wrong, maps) < gamma, (wrong, maps)
    assert upper(below, maps) < gamma, (below, maps)
    assert safe_maps > 0.9 * maps  # the maps say something: safe and unsafe regions both certified


def error_volume(truth: Truth, results: list[RegionResult], grid: int = 200) -> float:
    """The share of the box the map gets wrong: a condition in a region whose verdict is not its own side of τ,
    or in an undecided region."""
    ticks = (np.arange(grid) + 0.5) / grid
    points = np.stack(np.meshgrid(ticks, ticks, indexing="ij"), -1).reshape(-1, 2)
    safe = truth(points) >= TAU
    wrong = np.zeros(len(points), dtype=bool)
    for r in results:
        inside = r.region.contains(points)
        if r.verdict == "undecided":
            wrong |= inside
        else:
            wrong |= inside & (safe != (r.verdict == "safe"))
    return float(wrong.mean())


def test_the_map_converges_to_the_true_boundary_as_the_budget_grows():
    truth = Truth((Ramp(0.3, 2.0), Ramp(0.4, 1.5)))  # a steeper fall: η1 = τ near u0 = 0.35, u1 = 0.47
    budgets = [  # search rollouts, finest depth, a region's most rollouts
        (32, 2, 64),
        (64, 3, 256),
        (128, 4, 1024),
    ]
    errors = []
    rng = np.random.default_rng(7)
    for search_budget, depth, region_budget in budgets:
        settings = CertifySettings(threshold=TAU, gamma=0.05, look_size=16, region_budget=region_budget)
        search_settings = SearchSettings(budget=search_budget, initial=16, batch=8, bandwidth=0.1)
        partition_settings = PartitionSettings(min_depth=1, max_depth=depth)
        volumes = [
            error_volume(truth, make_map(truth, rng, search_settings, partition_settings, settings)) for _ in range(8)
        ]
        errors.append(np.mean(volumes))
    assert errors[0] > errors[1] > errors[2], errors
    assert errors[2] < 0.1, errors
