"""The `envelope` stage's result as a typed record (`uqdrive.pipeline.records`):
metrics/envelope/<method>-<replicate>.json, read back by ``read_record(EnvelopeResult, path, "envelope@<method>")``."""

from __future__ import annotations

from typing import Literal

from uqdrive.pipeline.records import record

Verdict = Literal["safe", "unsafe", "undecided"]


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
    verdict: Verdict
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
    regions' tests read), unread (run ahead of a test and not read, `uqdrive.safety.cells.Draws`), total."""

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
    verdicts: dict[str, int]
    volume: dict[str, float]
    search: EnvelopeSearch
    rollouts: dict[str, int]
    grid: GridCost
    seconds: float
