"""The results one stage writes and another reads, as typed records: a safety cell (metrics/safety/<cell>.json),
an avoid stage's result (metrics/avoid/<method>-<replicate>.json) and a controller's training metrics
(metrics/<experiment>/train/<replicate>/<method>.json).

The writer builds the record and `write_record` stores it; the reader gets it back by `read_record`, which
checks the file against the record (a key missing or unknown, a value of the wrong type) and fails in one line
naming the file and the key. So the file format is written down once, here, and the summaries, findings and the
report read attributes, not string keys.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from pydantic import ConfigDict, TypeAdapter, ValidationError
from pydantic.dataclasses import dataclass as _pydantic_dataclass

from uqdrive.files import write_json
from uqdrive.resolvers import noise_label
from uqdrive.schema import ConfigError, describe

R = TypeVar("R")
_RECORD = ConfigDict(extra="forbid")  # NaN is a value here (a mean over no frames), unlike in a config
_OPEN_RECORD = ConfigDict(extra="allow")  # method-specific keys beside the declared ones


def record(cls: type[R] | None = None, *, open_keys: bool = False):
    """A result file's record: frozen, every key declared (``open_keys``: others allowed and kept)."""

    def wrap(c: type[R]) -> type[R]:
        return _pydantic_dataclass(c, config=_OPEN_RECORD if open_keys else _RECORD, frozen=True)

    return wrap if cls is None else wrap(cls)


def write_record(path: str | Path, value: Any) -> Path:
    return write_json(path, as_dict(value))


def as_dict(value: Any) -> dict:
    """A record as plain JSON-able data, the keys an open record kept included."""
    data = dataclasses.asdict(value)
    extra = getattr(value, "__pydantic_extra__", None) or {}
    return {**data, **extra}


def read_record(cls: type[R], path: str | Path, stage: str) -> R:
    """The record in ``path``; a missing file names the ``stage`` that writes it, a stale one the key."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing; run the stage that writes it first: dvc repro {stage}")
    try:
        return TypeAdapter(cls).validate_python(json.loads(path.read_text()))
    except ValidationError as err:
        raise ConfigError(f"{path}: {describe(err.errors()[0], cls)}; rerun dvc repro {stage}") from None


def safety_cell_name(method: str, replicate: int, location: str, weather: str, noise: float) -> str:
    """A cell's name in file names and runs, as conf/safety.yaml's `safety.cell` spells it."""
    return f"{method}-seed{replicate}-{location}-{weather}-noise{noise_label(noise)}"


@record
class SafetyCell:
    """One offline-safety cell: η̂1 of one controller (method × replicate) at one condition, how its runs failed,
    and ``outcomes``: each rollout's verdict in index order ("1" safe), which pairs it with every other cell."""

    method: str
    replicate: int
    experiment: str
    location: str
    weather: str
    noise: float
    theta: float
    gamma: float
    scheme: str
    n: int
    base_seed: int
    family_size: int  # cells γ was spread over (1: the guarantee holds per cell)
    fixed_rollouts: int  # rollouts the scheme runs whatever the outcomes: the prefix exact tests may use
    eta1: float
    eta1_low: float
    eta1_high: float
    rollouts: int
    steps: int
    seconds: float
    collision_rate: float
    off_road_rate: float
    left_corridor_rate: float
    reached_goal_rate: float
    max_corridor_use: float
    mean_corridor_use: float | None
    mean_lateral_deviation: float
    mean_eta2: float | None  # None: the controller drew no η2 set (sequential draws acting on no warning)
    mean_mutual_information: float
    guaranteed: bool
    outcomes: str
    config_hash: str
    unread: int = 0  # rollouts run ahead of a sequential estimator that it never read: time spent, not error

    @property
    def condition(self) -> tuple[str, str, float]:
        return self.location, self.weather, self.noise

    @property
    def name(self) -> str:
        return safety_cell_name(self.method, self.replicate, self.location, self.weather, self.noise)

    @property
    def safe(self) -> np.ndarray:
        return np.frombuffer(self.outcomes.encode(), np.uint8) == ord("1")


# An avoid stage's warnings modes: off (only counted) and on (the configured thresholds) on the stage's seeds; off
# again and calibrated on fresh seeds the calibration never saw. Each pair is two cells on the same seeds.
MODES = ("off", "on", "fresh_off", "calibrated")
WARNINGS_OFF = ("off", "fresh_off")
FRESH = ("fresh_off", "calibrated")
PAIRS = (("on", "off"), ("calibrated", "fresh_off"))  # (warnings, the same seeds without)


@record
class AvoidCell:
    """One collision-avoidance cell (condition × warnings mode) of one controller."""

    eta1: float
    eta1_low: float
    eta1_high: float
    n: int
    handover_rate: float
    autonomy: float
    full_speed_fraction: float
    collision_rate: float
    off_road_rate: float
    passed_rate: float
    timeout_before_obstacle_rate: float
    handover_distance_min: float | None
    handover_distance_median: float | None
    handover_distances: list[float]
    mean_steps: float
    seconds: float
    reused: bool
    warning0_frames: int
    warning0_runs: int
    warning1_frames: int
    warning1_runs: int
    warning2_frames: int
    warning2_runs: int
    terminations: dict[str, int]
    guaranteed: bool
    scheme: str
    theta: float
    gamma: float
    family_size: int
    fixed_rollouts: int
    thresholds: dict[str, float]
    base_seed: int
    outcomes: str

    @property
    def safe(self) -> np.ndarray:
        return np.frombuffer(self.outcomes.encode(), np.uint8) == ord("1")


@record
class Mixture:
    """The unknown conditions as one uniform mixture: of their cells (Hoeffding's interval, fixed n), or the one
    cell whose rollouts drew their variant (its own estimate; ``variants``: each variant's runs and safe runs in
    the cell's fixed sample, where it has one)."""

    eta1: float
    eta1_low: float
    eta1_high: float
    theta: float
    gamma: float
    n: int
    autonomy: float
    interval: str
    variants: dict[str, dict[str, int]] = dataclasses.field(default_factory=dict)


@record
class CalibrationSummary:
    """The thresholds Learn-then-Test chose, what it certified (``guarantee``, in words), the replay at them and
    the closed-loop check on fresh seeds."""

    delta1: float
    delta2: float
    tau: float
    feasible: bool
    certified: int
    guarantee: str
    autonomy_target: float
    max_certifiable_target: float
    gamma: float
    missed_limit: float | None
    order: str
    calibration_runs: dict[str, int]
    learn_runs: dict[str, int]
    candidates: int
    replayed: dict[str, Any]
    fresh_seed_check: dict[str, Any]
    uncaught_variants: list[dict[str, Any]]
    replay_check: dict[str, dict[str, float]]


@record
class AvoidResult:
    """One avoid stage (method × replicate): every cell by condition and mode, the unknown mixtures, the
    calibration."""

    method: str
    replicate: int
    experiment: str
    cells: dict[str, dict[str, AvoidCell]]
    unknown: dict[str, Mixture]
    calibration: CalibrationSummary
    warning: dict[str, Any]
    samples_per_frame: int
    conditions: list[str]
    horizon_s: float
    speed: float
    seconds: float
    mlflow_run_ids: dict[str, str | None]


@record(open_keys=True)
class TrainMetrics:
    """A trained controller's validation metrics; each method adds its own keys (HMC its convergence
    diagnostics, MCD its dropout rates), kept and read by `get`."""

    method: str
    val_accuracy: float
    val_nll: float
    val_ece: float
    val_brier: float
    majority_baseline_accuracy: float
    train_frames: int
    val_frames: int
    eval_samples: int
    seed: int
    train_seconds: float
    diagnostics: str

    def get(self, key: str) -> Any:
        return (getattr(self, "__pydantic_extra__", None) or {}).get(key)


def read_safety_cells(folder: str | Path, grid: Any) -> list[SafetyCell]:
    """Every cell of the ``grid`` (its methods × replicates × locations × weathers × noises), as written."""
    return [
        read_record(SafetyCell, Path(folder) / f"{safety_cell_name(m, r, loc, w, x)}.json", "safety")
        for m in grid.methods
        for r in grid.replicates
        for loc in grid.locations
        for w in grid.weathers
        for x in grid.noises
    ]


def read_avoid_results(folder: str | Path, methods: list[str], replicates: list[int]) -> list[AvoidResult]:
    """Every method × replicate's avoid result, as written."""
    return [
        read_record(AvoidResult, Path(folder) / f"{m}-seed{r}.json", f"avoid@{m}-{r}")
        for m in methods
        for r in replicates
    ]
