"""The collision-avoidance experiment's plan: its config (unknown conditions, threshold calibration, the stage's
whole schema) and the validated settings a run works from (`build_settings`): the known and unknown conditions,
the warnings-off policy and the rollout job of each cell.

The world is uqdrive's obstacle road, or any Gymnasium world (``gym_world=<conf/gym_world/ file>``): the known
condition is the world as configured, each unknown one the world with some of its own config changed
(``avoid.unknown[i].world``: dotted keys under gym_world, e.g. the other vehicles' driver) or its frames noisier. A
Gymnasium world has no fixed hazard: a run is judged by its ``safe_if``, distances are metres driven along its own
path, and its rate and horizon are the world's.

What drives is the experiment's trained controller, or a user's policy that gives draws (``avoid.policy``: its own
n draws a frame, the warnings read at once by the paper's fixed tier rule, n = warning.samples)."""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Annotated, Any, Literal

import numpy as np
from omegaconf import DictConfig
from pydantic import Field

from uqdrive.avoid.calibration import fresh_check_runs, min_calibration_runs
from uqdrive.avoid.course import Course, CourseOf
from uqdrive.avoid.results import Mode
from uqdrive.models.model_stage import ModelStage
from uqdrive.policy.recipes import PolicyRecipe
from uqdrive.policy.warnings import WarningConfig, WarningRule
from uqdrive.resolvers import world_location
from uqdrive.safety.cells import EstimatorSettings
from uqdrive.safety.drive import Driver, DriveSection, resolve_driver
from uqdrive.safety.executors import RolloutJob, job_world
from uqdrive.safety.safe_sets import obstacle_pass_progress
from uqdrive.schema import (
    Bool,
    ConfigError,
    Count,
    NonNegative,
    OpenUnit,
    Seed,
    Str,
    Unit,
    invalid,
    schema,
    validate,
)
from uqdrive.sim import CameraConfig, VehicleConfig, build_geometry
from uqdrive.sim.condition import Condition, Mixture, WorldChoice
from uqdrive.sim.config import GymWorldConfig, ScenarioConfig, SimConfig, WeatherConfig
from uqdrive.sim.location import ByWorld
from uqdrive.stage_schemas import ExecutorSettings
from uqdrive.uq.multiplicity import split_gamma

KNOWN = "known"
UNKNOWN = "unknown"  # the mixture cell's condition (avoid.unknown_as=mixture)


@schema
class UnknownCondition:
    """One unknown condition of the avoid stage: a weather loaded under `weathers`, sensor noise, scenario changes;
    in a Gymnasium world, changes of the world's own config (``world``) and sensor noise."""

    name: Str
    weather: Str | None = None  # None: the known weather
    noise: NonNegative = 0.0
    scenario: dict[str, Any] = Field(default_factory=dict)  # fields of the obstacle scenario to change
    world: dict[str, Any] = Field(default_factory=dict)  # dotted keys under gym_world to change (a gym world's)

    def __post_init__(self) -> None:
        if self.name in (KNOWN, UNKNOWN):
            raise invalid("name", self.name, "is the training condition's or the unknown mixture's; choose another")


@schema(frozen=True)
class FreshCheckSettings:
    """The fresh-seed check of the deployed rule's known-condition autonomy (`calibration.fresh_seed_check`), sized
    in advance: Bonferroni over the ``controllers`` checked (each at the calibration's γ / controllers), with
    enough known-condition fresh runs to declare ``target`` met with probability ≥ ``power`` when the true
    autonomy is ``autonomy``."""

    target: OpenUnit
    autonomy: OpenUnit
    power: OpenUnit
    controllers: Count  # controllers the pipeline checks (methods × replicates): the correction's size

    def __post_init__(self) -> None:
        if not self.target < self.autonomy:
            raise invalid("avoid.calibration.fresh_check.autonomy", self.autonomy, f"must exceed target {self.target}")


@schema(frozen=True)
class CalibrationSettings:
    """Threshold calibration by Learn-then-Test (`uqdrive.avoid.calibration`): with probability ≥ 1 − ``gamma``
    every certified candidate keeps the replayed known-condition autonomy ≥ ``autonomy_target`` (and, with
    ``missed_limit``, each unknown condition's replayed missed-collision rate ≤ it); among the certified, the
    most replayed unknown-condition safety. The candidate grids are kept sorted and without repeats."""

    autonomy_target: OpenUnit
    gamma: OpenUnit  # family-wise error over the candidate grid
    margin_m: NonNegative  # extra stopping distance a saved run must have kept before its collision point
    deltas: Annotated[tuple[Unit, ...], Field(min_length=1)]  # candidates for δ1 and δ2 (δ2 <= δ1)
    taus: Annotated[tuple[NonNegative, ...], Field(min_length=1)]  # candidates for τ
    missed_limit: OpenUnit | None  # None: no constraint on the unknown conditions' missed collisions
    calibration_fraction: Annotated[float, Field(gt=0, le=1)]  # share of run indices the tests use
    order: Literal["firing", "learned"]  # the fixed sequence: a priori, or Pareto Testing on the other runs
    fresh_check: FreshCheckSettings

    def fresh_level(self) -> float:
        """Each controller's fresh-seed check: γ split over the controllers checked."""
        return split_gamma(self.gamma, self.fresh_check.controllers)

    def fresh_runs(self) -> int:
        """Known-condition fresh runs the check needs (`calibration.fresh_check_runs`)."""
        check = self.fresh_check
        return fresh_check_runs(check.target, check.autonomy, self.fresh_level(), check.power)

    def __post_init__(self) -> None:
        object.__setattr__(self, "deltas", tuple(sorted(set(self.deltas))))
        object.__setattr__(self, "taus", tuple(sorted(set(self.taus))))


@schema(frozen=True, kw_only=True)
class AvoidSection(DriveSection, EstimatorSettings):
    """conf/avoid.yaml's `avoid`: every cell's estimator (scheme, theta, gamma, look_size, base_seed), what drives
    (`DriveSection`: the trained model, or a user's policy that gives draws, its own n a frame; the controller draws
    warning.samples; T long enough for a run slowed by warnings to pass the obstacle, checked), the world and the
    calibration. Warnings-off cells record what calibration replays."""

    name: Str  # <method>-<replicate>: the stage's cells, files and runs
    validation_seed: Seed
    family_wise: Bool  # spend γ over this controller's cells (conditions × modes): all of them at once
    unknown: Annotated[tuple[UnknownCondition, ...], Field(min_length=1)]
    unknown_as: Literal["cells", "mixture"]  # a cell per variant, or one whose rollouts draw theirs (avoid_mixture)
    min_rollouts: Seed  # every cell runs at least this many (the sample paired tests and the calibration use)
    calibration: CalibrationSettings
    data_dir: Str
    clips: Annotated[int, Field(ge=0, strict=True)]  # the worst failures of each cell drawn as clips (0: none)

    def __post_init__(self) -> None:
        names = [c.name for c in self.unknown]
        if len(set(names)) != len(names):
            raise invalid("unknown", names, "must have unique names")


@schema(root=True)
class AvoidStage(WorldChoice, SimConfig, ModelStage):
    """`stages/avoid.py`: collision avoidance with the warning system, one method; the known condition is the
    stage's world (`WorldChoice`: the obstacle road in the training weather, or a Gymnasium world) at ``noise``. In a
    Gymnasium world, T and the control rate are the world's (gym_world.horizon_steps, gym_world.control_hz), and the
    car, camera and avoid.horizon_s are the pybullet world's, unused (the replay's car model aside)."""

    weathers: dict[str, WeatherConfig]  # those `avoid.unknown` may name
    warning: WarningConfig
    executor: ExecutorSettings
    avoid: AvoidSection

    def __post_init__(self) -> None:
        super().__post_init__()
        self.choose(ByWorld(road=self._check_road, gym=self._check_gym_unknown))

    def _check_road(self, scenario: ScenarioConfig) -> None:
        """On our obstacle road: unknown conditions of our weathers and scenario changes, each checked here."""
        for i, condition in enumerate(self.avoid.unknown):
            if condition.world:
                raise invalid(f"avoid.unknown[{i}].world", condition.world, "changes a gym_world; name one or drop it")
        if not scenario.has_obstacle:
            raise invalid("scenario.kind", scenario.kind, "must be 'obstacle' for the avoid stage")
        if self.avoid.speed > self.vehicle.max_speed:
            raise invalid("avoid.speed", self.avoid.speed, f"must be <= vehicle.max_speed={self.vehicle.max_speed}")
        loaded = {self.weather.name, *self.weathers}
        for i, condition in enumerate(self.avoid.unknown):
            if condition.weather is not None and condition.weather not in loaded:
                raise invalid(
                    f"avoid.unknown[{i}].weather",
                    condition.weather,
                    f"is not loaded; choose one of {sorted(loaded)} or add +weather@weathers.{condition.weather}="
                    f"{condition.weather}",
                )
            validate(ScenarioConfig, {**self.scenario.to_dict(), **condition.scenario}, f"avoid.unknown[{i}].scenario")

    def _check_gym_unknown(self, world: GymWorldConfig) -> None:
        """A Gymnasium world's unknown conditions change its own config or noise; a weather or scenario of ours is
        refused (the env has none), and each changed world is checked here, before any rollout."""
        for i, condition in enumerate(self.avoid.unknown):
            for key in ("weather", "scenario"):
                if getattr(condition, key):
                    raise invalid(
                        f"avoid.unknown[{i}].{key}",
                        getattr(condition, key),
                        f"is uqdrive's: {world.env_id} has no {key} condition (change its config: world)",
                    )
            unknown_world(world, condition, f"avoid.unknown[{i}].world")


@dataclasses.dataclass(frozen=True)
class AvoidSettings:
    """Everything a stage run needs, validated (``stage``: the whole config, its paths among it); ``spec`` is the
    warnings-off policy (uqdrive's trained controller or a user's policy), ``driver.warned`` it acting on a rule."""

    stage: AvoidStage
    method: str  # the trained model's method, or a user's policy's name
    seed: int  # the replicate's training seed
    name: str  # <method>-<replicate>
    spec: PolicyRecipe
    rule: WarningRule  # the configured warnings, as the controller deploys them and the calibration replays them
    driver: Driver  # what drives (`resolve_driver`): ``spec`` acting on a rule's warnings (`Driver.warned`)
    estimator: EstimatorSettings
    validation_seed: int
    known: Condition
    unknown: tuple[Condition, ...] | tuple[Mixture]  # each variant its own cell, or one mixture cell
    calibration: CalibrationSettings
    camera: CameraConfig
    vehicle: VehicleConfig
    control_hz: float
    horizon_s: float
    executor: ExecutorSettings
    progress: bool
    family_size: int  # cells the estimator's γ is spread over (1: per cell)
    min_rollouts: int  # every cell runs at least this many, whatever its estimator reads

    @property
    def conditions(self) -> tuple[Condition | Mixture, ...]:
        return (self.known, *self.unknown)

    def fixed_rollouts(self) -> int:
        """Rollouts every cell runs whatever its outcomes: the prefix paired tests and the calibration may use."""
        return max(self.estimator.fixed_rollouts(), self.min_rollouts)

    def job(self, where: Condition | Mixture, rule: WarningRule | None, base_seed: int) -> RolloutJob:
        """The rollouts of one cell: ``rule`` None drives without the warning system (on the same draws)."""
        policy = self.spec if rule is None else self.driver.warned(rule)
        return RolloutJob(policy, where, base_seed, self.camera, self.vehicle, self.control_hz, self.horizon_s)

    def replay_args(self) -> dict[str, float]:
        """The car and calibration settings the threshold replay needs (`uqdrive.avoid.calibration.replay`); a
        Gymnasium world's car is not ours: the replay brakes it within our car's limits, from cruise speed."""
        start = self.known.visit(CourseOf()).start_speed(self.spec.speed)
        return {
            "control_hz": self.control_hz,
            "cruise": self.spec.speed,
            "start_speed": min(start, self.vehicle.max_speed),
            "max_accel": self.vehicle.max_accel,
            "max_brake": self.vehicle.max_brake,
            "margin_m": self.calibration.margin_m,
        }

    def geometries(self) -> dict[str, Course]:
        """The course per condition name, for distances along the road (a Gymnasium world's road is the env's own:
        distances are then along each run's path, `OwnPath`)."""

        def geometry(where: Condition | Mixture) -> Course:  # a mixture's road: the known one's
            return (where.single or self.known).visit(CourseOf())

        return {c.name: geometry(c) for c in self.conditions}


def unknown_world(world: GymWorldConfig, item: UnknownCondition, key: str) -> GymWorldConfig:
    """A Gymnasium world's unknown condition: the world with the condition's changes, as its own location (only
    noisier frames: the world itself)."""
    return world.changed(item.world, world_location(world.name, item.name), key) if item.world else world


def _unknown_conditions(stage: AvoidStage) -> tuple[Condition, ...] | tuple[Mixture]:
    """The unknown conditions, each a world: the known scenario with the condition's changes, a loaded weather (a
    Gymnasium world: the world with the condition's changes); with ``unknown_as: mixture``, one mixture whose
    rollouts draw among them (roads and obstacle places alike)."""
    unknown = stage.avoid.unknown

    def in_world(world: GymWorldConfig) -> tuple[Condition, ...]:
        key = "avoid.unknown.world"
        return tuple(Condition(unknown_world(world, item, key), None, item.noise, item.name) for item in unknown)

    def on_road(scenario: ScenarioConfig) -> tuple[Condition, ...]:
        weathers = {stage.weather.name: stage.weather, **stage.weathers}
        return tuple(
            Condition(
                ScenarioConfig.from_config({**scenario.to_dict(), **item.scenario}),
                weathers[item.weather or stage.weather.name],
                item.noise,
                item.name,
            )
            for item in unknown
        )

    each = stage.choose(ByWorld(road=on_road, gym=in_world))
    return each if stage.avoid.unknown_as == "cells" else (Mixture(UNKNOWN, each),)


def check_horizon(
    horizon: float, warning: WarningConfig, speed: float, scenario: ScenarioConfig, vehicle: VehicleConfig
) -> float:
    """The horizon must let a run that warnings slow down (but do not stop) pass the obstacle: a timeout
    before it would be a non-answer, neither safe nor a collision."""
    slowest = (
        min(a.speed for a in warning.actions if not a.handover) if any(not a.handover for a in warning.actions) else 1.0
    )
    if slowest <= 0:
        raise ConfigError(
            "warning.actions: a slow-down to speed 0 without a hand-over never passes the obstacle; "
            "give it a speed > 0 or handover: true"
        )
    distance = obstacle_pass_progress(build_geometry(scenario), vehicle.length) - scenario.start_distance
    needed = distance / (slowest * speed) + 1.0  # + 1 s for the start jitter and speed changes
    if horizon < needed:
        raise ConfigError(
            f"avoid.horizon_s={horizon:g} is too short: a run slowed to {slowest * speed:g} m/s needs "
            f"{needed:.1f} s to pass the obstacle ({distance:.0f} m); set at least {np.ceil(needed):g}"
        )
    return horizon


def build_settings(cfg: DictConfig) -> AvoidSettings:
    """Validate the stage's config and the model file; raises before any rollout, naming key and value."""
    stage = validate(AvoidStage, cfg)
    avoid, warning = stage.avoid, stage.warning
    cells = 1 + (len(avoid.unknown) if avoid.unknown_as == "cells" else 1)
    family_size = cells * len(Mode) if avoid.family_wise else 1
    estimator = dataclasses.replace(
        avoid.estimator, gamma=split_gamma(avoid.gamma, family_size), base_seed=stage.rollout_seeds(avoid.base_seed)
    )
    passes = partial(check_horizon, avoid.horizon_s, warning, avoid.speed, vehicle=stage.vehicle)
    horizon = stage.choose(ByWorld(road=passes, gym=lambda world: avoid.horizon_s))  # a Gymnasium world's own
    car = job_world(stage.condition(KNOWN), stage.camera, stage.vehicle, float(stage.control_hz), horizon)
    calibration = avoid.calibration
    needed = min_calibration_runs(calibration.autonomy_target, calibration.gamma, calibration.calibration_fraction)
    fixed = max(estimator.fixed_rollouts(), avoid.min_rollouts)
    if fixed < needed:
        raise ConfigError(
            f"avoid.calibration.autonomy_target={calibration.autonomy_target:g} cannot be certified with "
            f"{fixed} known-condition runs (it needs {needed}); lower it, raise avoid.min_rollouts or tighten "
            "avoid.theta"
        )
    if calibration.order == "learned" and calibration.calibration_fraction == 1:
        raise ConfigError("avoid.calibration.order='learned' needs avoid.calibration.calibration_fraction < 1")
    drive, rule = _driver(stage, car, estimator.base_seed)
    return AvoidSettings(
        stage,
        drive.method,
        stage.seed,
        avoid.name,
        drive.spec,
        rule,
        drive,
        estimator,
        stage.rollout_seeds(avoid.validation_seed),
        stage.condition(KNOWN),
        _unknown_conditions(stage),
        calibration,
        car["camera"],
        car["vehicle"],
        car["control_hz"],
        car["horizon_s"],
        stage.executor,
        stage.progress,
        family_size,
        avoid.min_rollouts,
    )


def _driver(stage: AvoidStage, car: dict[str, Any], base_seed: int) -> tuple[Driver, WarningRule]:
    """What drives (`resolve_driver`: the trained model, its file checked here, a controller drawing warning.samples
    a frame as ``avoid.draws`` says; or a user's policy, run on a first frame here, its own n draws a frame read at
    once by the paper's fixed tier rule at warning.theta, warning.gamma) and the rule its warnings act by (refused
    here, before any rollout, if its tier rule errs above γ). One line, before any rollout, if the policy gives no
    draws (its warnings and their calibration read them) or another number of them than the rule reads."""
    avoid, warning = stage.avoid, stage.warning
    drive = resolve_driver("avoid", avoid, stage, warning.samples, stage.condition(KNOWN).native)
    rule = WarningRule(warning, drive.warning_draws)
    draws = drive.probe(RolloutJob(drive.spec, stage.condition(KNOWN), base_seed, **car))
    if not draws:
        raise ConfigError(
            f"{drive.source}: the avoid stage needs a policy that gives draws (Action.draws: its warnings and their "
            f"calibration read them); {drive.name} gave none"
        )
    if draws != rule.cap:
        raise ConfigError(
            f"{drive.source}: {drive.name} gives {draws} draws a frame; the warning rule reads {rule.cap} "
            "(warning.samples: Chernoff's n for warning.theta, warning.gamma)"
        )
    return drive, rule
