"""The avoid stage's records (metrics/avoid/<method>-<replicate>.json): every cell by condition and warnings mode,
each cell's outcomes in rollout order so cells on the same seeds pair, the unknown mixtures and the calibration
(what Learn-then-Test certified, `uqdrive.avoid.calibration`, and its closed-loop checks)."""

from __future__ import annotations

import dataclasses
from enum import StrEnum
from pathlib import Path

import numpy as np

from uqdrive.policy.draws import DrawSettings
from uqdrive.records import flattened, read_record, record
from uqdrive.safety.cell_records import ESTIMATE_KEYS
from uqdrive.safety.failures import RolloutFailure
from uqdrive.uq.estimators import Estimate


class Mode(StrEnum):
    """An avoid cell's warnings: off (only counted) and on (the configured thresholds) on the stage's seeds; off again
    and calibrated on fresh seeds the calibration never saw. Each of `PAIRS` is two cells on the same seeds."""

    OFF = "off"
    ON = "on"
    FRESH_OFF = "fresh_off"
    CALIBRATED = "calibrated"

    @property
    def warnings_off(self) -> bool:
        return self in (Mode.OFF, Mode.FRESH_OFF)

    @property
    def fresh(self) -> bool:
        """Drives the validation seeds, which the calibration never saw."""
        return self in (Mode.FRESH_OFF, Mode.CALIBRATED)


PAIRS = ((Mode.ON, Mode.OFF), (Mode.CALIBRATED, Mode.FRESH_OFF))  # (warnings, the same seeds without)


@record
class ActionRecord:
    """One warning level's action as deployed (`uqdrive.policy.warnings.WarningAction`)."""

    speed: float
    alert: bool
    handover: bool


@record
class TierRecord:
    """The tier rule as deployed (`uqdrive.uq.tier`'s ``settings()``): its exact wrong-tier error included."""

    scheme: str
    delta1: float
    delta2: float
    theta: float
    gamma: float
    looks: list[int]
    wrong_tier_error: float
    middle_guaranteed: bool


@record
class RuleRecord:
    """A warning rule as a record keeps it (`uqdrive.policy.warnings.WarningRule.to_dict`): thresholds, actions
    by level (warning0/1/2), draw settings, tier rule."""

    delta1: float
    delta2: float
    tau: float
    theta: float
    gamma: float
    hold_s: float
    samples: int
    actions: dict[str, ActionRecord]
    draws: DrawSettings
    tier: TierRecord


@record
class UncaughtVariant:
    """An unknown condition whose unsafe warnings-off runs no candidate's replay saves: η̂1 without warnings and
    the medians over its runs of each run's lowest η2 and highest MI (nats)."""

    condition: str
    eta1_off: float
    min_eta2_median: float
    max_mutual_information_median: float


@record
class AvoidCell:
    """One collision-avoidance cell (condition × warnings mode) of one controller."""

    estimate: Estimate = flattened(ESTIMATE_KEYS, left=("condition",))  # η̂1, its interval, θ, γ, scheme, n
    handover_rate: float
    autonomy: float
    full_speed_fraction: float
    collision_rate: float
    off_road_rate: float
    passed_rate: float  # past the obstacle (a Gymnasium world: safe to the end of its episode)
    # timed out short of the goal (a Gymnasium world: its safe_if failed at the last step)
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
    family_size: int
    fixed_rollouts: int
    thresholds: dict[str, float]
    base_seed: int
    outcomes: str
    failures: list[RolloutFailure] = dataclasses.field(default_factory=list)  # the failing runs, worst margin first

    @property
    def safe(self) -> np.ndarray:
        return np.frombuffer(self.outcomes.encode(), np.uint8) == ord("1")


@record
class MixtureEstimate:
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
class Certificate:
    """What Learn-then-Test certified, in the stage's record: the chosen thresholds and the deployed rule (``rule``:
    thresholds, actions, draws, the tier rule with its exact wrong-tier error and whether the middle tier is
    guaranteed), whether it is certified (``feasible``; False: nothing was, and it is the never-firing one), how many
    candidates are, the claim in words (``guarantee``, naming the deployed rule, or why there is none), the runs per
    condition in each split, the highest autonomy target the known calibration runs could certify at level γ (no
    hand-over in any), the chosen candidate's replayed row and the candidates whose tier rule was refused."""

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
    replayed: dict[str, float | int | bool]  # the chosen row of the replayed table, thresholds left out
    rule: RuleRecord
    middle_guaranteed: bool
    refused: dict[str, str]  # "delta1/delta2" → why its tier rule was refused


@record
class FreshSeedCheck:
    """The deployed rule's known-condition autonomy on fresh closed-loop runs, by one exact test fixed in advance:
    H0 "autonomy < ``target``" (autonomy: the share of runs without a hand-over), one-sided exact binomial,
    p = P(Bin(``runs``, target) ≥ ``autonomous``). ``target_met``: H0 rejected at ``level`` — a rule whose autonomy
    is below the target is declared to meet it with probability ≤ level."""

    runs: int
    autonomous: int
    target: float
    level: float
    p_value: float
    target_met: bool


@record
class FreshSeedRecord:
    """The calibrated rule in closed loop on fresh seeds: its known-condition autonomy tested by one exact test fixed
    in advance (``check``), and its η̂1 known and in the unknown conditions (descriptive)."""

    check: FreshSeedCheck
    known_autonomy: float
    known_eta1: float
    unknown_eta1: float
    base_seed: int


@record
class CalibrationSummary:
    """What Learn-then-Test certified (``certificate``), the closed-loop check on fresh seeds, the unknown
    conditions no threshold catches and the replay at the configured thresholds against closed loop."""

    certificate: Certificate
    fresh_seed_check: FreshSeedRecord
    uncaught_variants: list[UncaughtVariant]
    replay_check: dict[str, dict[str, float]]


@record
class AvoidResult:
    """One avoid stage (method × replicate): every cell by condition and mode, the unknown mixtures, the
    calibration."""

    method: str
    replicate: int
    experiment: str
    cells: dict[str, dict[Mode, AvoidCell]]  # condition → mode → cell
    unknown: dict[Mode, MixtureEstimate]
    calibration: CalibrationSummary
    warning: RuleRecord
    samples_per_frame: int
    conditions: list[str]
    horizon_s: float
    speed: float
    seconds: float

    def cell(self, condition: str, mode: Mode) -> AvoidCell:
        return self.cells[condition][mode]


def read_avoid_results(folder: str | Path, methods: list[str], replicates: list[int]) -> list[AvoidResult]:
    """Every method × replicate's avoid result, as written."""
    return [
        read_record(AvoidResult, Path(folder) / f"{m}-seed{r}.json", f"avoid@{m}-{r}")
        for m in methods
        for r in replicates
    ]
