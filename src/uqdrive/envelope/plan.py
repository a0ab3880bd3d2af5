"""An operating envelope's plan (conf/envelope.yaml): its schema, and the validated stage it runs — the condition
space, the controller, the rollout jobs that drive it — checked before any rollout. The world is uqdrive's or a
Gymnasium world (``gym_world=…``: its axes are noise and numbers of its own config, `uqdrive.envelope.space`)."""

from __future__ import annotations

import dataclasses
from typing import Annotated

from omegaconf import DictConfig
from pydantic import Field

from uqdrive.envelope.certify import CertifySettings, clean_run_to_safe
from uqdrive.envelope.partition import PartitionSettings
from uqdrive.envelope.search import SearchSettings
from uqdrive.envelope.sources import Listed, UniformIn
from uqdrive.envelope.space import BLEND, Axis, AxisSettings, BlendSettings, ConditionSpace
from uqdrive.models.model_stage import ModelStage
from uqdrive.policy.recipes import PolicyRecipe
from uqdrive.safety.drive import CorridorDrive, resolve_driver
from uqdrive.safety.executors import RolloutJob, job_world
from uqdrive.schema import ConfigError, Seed, invalid, schema, validate
from uqdrive.sim.condition import WorldChoice
from uqdrive.sim.config import ScenarioConfig, SimConfig, WeatherConfig
from uqdrive.sim.location import ByWorld, nothing
from uqdrive.stage_schemas import ExecutorSettings
from uqdrive.uq.multiplicity import split_gamma

Axes = Annotated[tuple[AxisSettings, ...], Field(min_length=2, max_length=3)]


@schema(frozen=True, kw_only=True)
class EnvelopeSection(CorridorDrive, CertifySettings):
    """conf/envelope.yaml's `envelope`: the axes, the target and guarantee (threshold, gamma, theta, look_size,
    region_budget), both phases' settings, what drives the map (`CorridorDrive`) and the outputs."""

    axes: Axes
    blend: BlendSettings
    base_seed: Seed  # phase one's rollouts use base_seed + 0 … budget − 1; region r's the next region_budget after
    search: SearchSettings
    partition: PartitionSettings


@schema(root=True)
class EnvelopeStage(WorldChoice, SimConfig, ModelStage):
    """`stages/envelope.py`: the certified map of one controller (``model``) over ``envelope.axes``, around the
    stage's world (`WorldChoice`: its scenario, weather and noise, unless an axis varies them; or a Gymnasium world,
    whose rate and horizon are its own: the car, camera, envelope.horizon_s and envelope.half_width are then the
    pybullet world's, unused)."""

    weathers: dict[str, WeatherConfig]  # those envelope.blend may name
    executor: ExecutorSettings
    envelope: EnvelopeSection

    def __post_init__(self) -> None:
        super().__post_init__()
        self.choose(ByWorld(road=self._check_road, gym=nothing))  # a Gymnasium world's axes: `ConditionSpace`'s

    def _check_road(self, scenario: ScenarioConfig) -> None:
        """The speed our car can reach, and the weathers a blend axis names, loaded."""
        env = self.envelope
        if env.speed > self.vehicle.max_speed:
            raise invalid("envelope.speed", env.speed, f"must be <= vehicle.max_speed={self.vehicle.max_speed}")
        if any(a.key == BLEND for a in env.axes):
            for key, name in (("from", env.blend.start), ("to", env.blend.to)):
                if name not in self.weathers:
                    raise invalid(
                        f"envelope.blend.{key}", name, f"is not loaded; choose one of {sorted(self.weathers)}"
                    )


@dataclasses.dataclass(frozen=True)
class Envelope:
    """A validated stage: the condition space, the policy and the settings."""

    stage: EnvelopeStage
    method: str
    space: ConditionSpace
    policy: PolicyRecipe

    @property
    def settings(self) -> EnvelopeSection:
        return self.stage.envelope

    @property
    def base_seed(self) -> int:
        """The first rollout seed of the map (its replicate's block: `uqdrive.stage_schemas.SEED_BLOCK`)."""
        return self.stage.rollout_seeds(self.settings.base_seed)

    def listed(self, points: tuple[tuple[float, ...], ...]) -> Listed:
        return Listed(self.space, points)

    def uniform_in(self, low: tuple[float, ...], high: tuple[float, ...]) -> UniformIn:
        return UniformIn(self.space, low, high)

    def job(self, source: Listed | UniformIn, base_seed: int) -> RolloutJob:
        s = self.stage
        env = s.envelope
        world = job_world(s.condition(), s.camera, s.vehicle, s.control_hz, env.horizon_s, env.half_width)
        return RolloutJob(policy=self.policy, where=source, base_seed=base_seed, **world)


def build_envelope(cfg: DictConfig) -> Envelope:
    """Validate the stage's config, every condition of a lattice over the axes and the model file, before any
    rollout (a bad value is one line naming its key)."""
    stage = validate(EnvelopeStage, cfg)
    env = stage.envelope
    base = stage.condition()
    blend = None
    if any(a.key == BLEND for a in env.axes):  # between two of our weathers (a Gymnasium world has none)
        blend = stage.choose(ByWorld(road=lambda _: (stage.weathers[env.blend.start], stage.weathers[env.blend.to]),
                                     gym=nothing))  # fmt: skip
    try:
        space = ConditionSpace(tuple(Axis.of(a, base) for a in env.axes), base, blend)
    except ValueError as err:
        raise ConfigError(str(err)) from None
    space.check()
    _check_budget(env, space.dim)
    method, policy = _driver(stage)
    return Envelope(stage, method, space, policy)


def _driver(stage: EnvelopeStage) -> tuple[str, PolicyRecipe]:
    """What drives the map's rollouts and its name (`resolve_driver`: the trained model loaded here, a missing or
    mismatched file naming the stage that trains it; or a user's policy, run on a first frame here)."""
    env, where = stage.envelope, stage.condition()
    drive = resolve_driver("envelope", env, stage, env.samples, where.native)
    world = job_world(where, stage.camera, stage.vehicle, stage.control_hz, env.horizon_s, env.half_width)
    drive.probe(RolloutJob(drive.spec, where, env.base_seed, **world))
    return drive.method, drive.spec


def _check_budget(env: EnvelopeSection, dim: int) -> None:
    """A region must be able to end safe: with the most regions the partition can make (each at its share of γ),
    some run of safe rollouts within the region's budget must certify it."""
    regions = 2 ** (dim * env.partition.max_depth)
    if clean_run_to_safe(env, split_gamma(env.gamma, regions)) is None:
        raise ConfigError(
            f"envelope.region_budget={env.region_budget} is too small: with up to {regions} regions "
            f"(partition.max_depth={env.partition.max_depth}) no region could be certified safe, even with every "
            "rollout safe; raise it or lower max_depth"
        )
