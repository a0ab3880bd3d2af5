"""The `envelope` stage's result as a typed record (`uqdrive.records`):
metrics/envelope/<method>-<replicate>.json, read back by ``read_record(EnvelopeResult, path, "envelope@<method>")``."""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

from uqdrive.envelope.certify import RegionResult, RegionVerdict, grid_cost
from uqdrive.envelope.plan import Envelope
from uqdrive.envelope.search import SearchResult
from uqdrive.envelope.space import ConditionSpace
from uqdrive.records import record


@record
class EnvelopeAxis:
    """A condition axis: its config key and the range conditions were drawn from."""

    key: str
    range: list[float]  # [low, high]


@record
class EnvelopeRegion:
    """One region of the map and how its test ended.

    ``order``: its place in phase two (regions go by the decisions their tests are expected to make per rollout);
    ``gamma``: its share of the family-wise γ; ``undecided_by``: ``region_budget`` (its own budget ran out) or
    ``certify_budget`` (phase two's did, before or while it ran), None when decided."""

    name: str
    order: int
    bounds: dict[str, list[float]]  # axis key → [low, high]
    depth: int
    volume: float  # its share of the box
    gamma: float
    verdict: RegionVerdict
    rollouts: int
    safe_rollouts: int
    eta1_hat: float | None  # None: no rollout ran
    undecided_by: Literal["region_budget", "certify_budget"] | None


@record
class EnvelopeSearch:
    """Phase one's rollouts: each one's condition (``points``: values in the order of the axes) and outcome
    (``outcomes``: "1" safe, "0" not, in the order run), and the sizes of its rounds."""

    rollouts: int
    failures: int
    rounds: list[int]
    points: list[list[float]]
    outcomes: str


@record
class GridCost:
    """The rollouts a grid at the partition's finest resolution would need with a fixed-n exact (Clopper–Pearson)
    interval of half-width ``theta`` per cell: family-wise at γ like the map (``rollouts``, each cell at
    ``gamma_per_cell``), and each cell at γ alone (``rollouts_per_cell_gamma``)."""

    theta: float
    cells: int
    gamma_per_cell: float
    per_cell: int
    rollouts: int
    rollouts_per_cell_gamma: int


@record
class EnvelopeResult:
    """One controller's certified map: ``regions`` with their verdicts, which hold together as ``guarantee`` says;
    ``verdicts`` and ``volume`` count them and their share of the box; ``rollouts``: search, certify (what the
    regions' tests read), unread (run ahead of a test and not read, `uqdrive.safety.cells.OutcomeStream`), total."""

    method: str
    replicate: int
    experiment: str
    location: str
    weather: str  # of every condition, unless an axis is weather.blend
    noise: float  # of every condition, unless an axis is noise
    axes: list[EnvelopeAxis]
    blend: dict[str, str] | None  # {"from": ..., "to": ...} of a weather.blend axis
    threshold: float
    gamma: float
    theta: float
    guarantee: str
    base_seed: int
    regions: list[EnvelopeRegion]
    verdicts: dict[RegionVerdict, int]
    volume: dict[RegionVerdict, float]
    search: EnvelopeSearch
    rollouts: dict[str, int]
    grid: GridCost
    seconds: float


def guarantee(theta: float) -> str:
    """What the map's verdicts say, together (each region's test at its share of γ, the union bound over them)."""
    safe, unsafe = ("eta1 >= threshold", "eta1 < threshold")
    if theta > 0:
        safe, unsafe = ("eta1 > threshold - theta", "eta1 < threshold + theta")
    return (
        f"family-wise, of region averages: with probability >= 1 - gamma, at once, every region marked safe has "
        f"{safe} and every region marked unsafe has {unsafe}, where a region's eta1 is its average: the probability "
        "that a rollout at a condition drawn uniformly in the region, on a fresh seed, stays in the safe set (not "
        "eta1 at every point of it)"
    )


def _values(space: ConditionSpace, unit: np.ndarray) -> list[float]:
    """A point of the unit box as the axes' values (unrounded)."""
    return [a.low + float(u) * (a.high - a.low) for a, u in zip(space.axes, unit)]


def _region(space: ConditionSpace, r: RegionResult, order: int, region_budget: int) -> EnvelopeRegion:
    low, high = _values(space, np.asarray(r.region.low)), _values(space, np.asarray(r.region.high))
    undecided_by = None
    if r.verdict == RegionVerdict.UNDECIDED:
        undecided_by = "region_budget" if r.rollouts >= region_budget else "certify_budget"
    return EnvelopeRegion(
        name=r.region.name,
        order=order,
        bounds={a.key: [lo, hi] for a, lo, hi in zip(space.axes, low, high)},
        depth=r.region.depth,
        volume=r.region.volume,
        gamma=r.gamma,
        verdict=r.verdict,
        rollouts=r.rollouts,
        safe_rollouts=r.safe,
        eta1_hat=r.safe / r.rollouts if r.rollouts else None,
        undecided_by=undecided_by,
    )


def envelope_result(
    envelope: Envelope,
    found: SearchResult,
    results: list[RegionResult],
    order: list[int],
    seconds: float,
    unread: int,
) -> EnvelopeResult:
    """The stage's record: ``results`` in depth-first order, ``order`` the order phase two took them in;
    ``unread``: rollouts the regions' cells ran ahead of their tests, which the tests never read."""
    env, space, stage = envelope.settings, envelope.space, envelope.stage
    regions = [_region(space, r, order.index(i), env.region_budget) for i, r in enumerate(results)]
    searched, certified = len(found.outcomes), sum(r.rollouts for r in results)
    return EnvelopeResult(
        method=envelope.method,
        replicate=stage.seed,
        experiment=stage.experiment.name,
        location=space.base.location,
        weather=space.base.weather_name,
        noise=stage.noise,
        axes=[EnvelopeAxis(a.key, [a.low, a.high]) for a in space.axes],
        blend={"from": space.blend[0].name, "to": space.blend[1].name} if space.blend else None,
        threshold=env.threshold,
        gamma=env.gamma,
        theta=env.theta,
        guarantee=guarantee(env.theta),
        base_seed=envelope.base_seed,
        regions=regions,
        verdicts={v: sum(r.verdict == v for r in regions) for v in RegionVerdict},
        volume={v: sum(r.volume for r in regions if r.verdict == v) for v in RegionVerdict},
        search=EnvelopeSearch(
            rollouts=searched,
            failures=int(searched - found.outcomes.sum()),
            rounds=list(found.rounds),
            points=[_values(space, p) for p in found.points],
            outcomes="".join(str(int(y)) for y in found.outcomes),
        ),
        rollouts={"search": searched, "certify": certified, "unread": unread, "total": searched + certified + unread},
        grid=GridCost(theta=env.grid_theta, **grid_cost(space.dim, env.partition.max_depth, env.grid_theta, env.gamma)),
        seconds=seconds,
    )


@dataclasses.dataclass(frozen=True)
class EnvelopeRun:
    """The map and whether it was ``reused``: every rollout replayed from the cells' logs (nothing simulated)."""

    result: EnvelopeResult
    reused: bool
