"""Config schemas of the simulated world (`uqdrive.schema`): every knob is a field, so that a new
location, weather or car is a yaml file that lists only what differs from these defaults."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, TypeVar, get_args

from pydantic import Field, Strict

from uqdrive.resolvers import find_conf
from uqdrive.schema import (
    Bool,
    Color,
    ConfigError,
    Count,
    Float,
    Int,
    NonNegative,
    Positive,
    Seed,
    Str,
    Unit,
    defaults,
    invalid,
    plain,
    schema,
    validate,
)

from .gym_hooks import hooks_class

ScenarioKind = Literal["straight", "obstacle", "roundabout"]
SCENARIO_KINDS = get_args(ScenarioKind)

SectionType = TypeVar("SectionType", bound="Section")


class Section:
    """A config section's schema, built from a mapping as the section ``section`` of a stage's config."""

    section: ClassVar[str] = ""

    @classmethod
    def from_config(cls: type[SectionType], mapping: Mapping[str, Any] | None = None, **overrides: Any) -> SectionType:
        """From a dict or DictConfig (the missing keys take their defaults); errors name ``<section>.<key>``."""
        return validate(cls, {**(plain(mapping) or {}), **overrides}, cls.section)

    @classmethod
    def from_yaml(cls: type[SectionType], path) -> SectionType:
        """From a config-group file, honouring its Hydra ``defaults`` list as ``hydra.compose`` would: sibling
        files (a location that inherits the roundabout) and ``schema``, these defaults."""
        return cls.from_config(_load_group_file(Path(path)))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)  # type: ignore[call-overload]


@schema
class ScenarioConfig(Section):
    """Road layout and surroundings of one location, in metres.

    ``kind`` picks the layout; the other fields parametrise it. Straight roads run along +x
    with the right lane (right-hand traffic) at y = -lane_width / 2. Roundabouts are centred at
    the origin, the ego enters from the south arm and leaves by the first exit (east arm).
    """

    section: ClassVar[str] = "scenario"

    name: Str = "straight"
    kind: ScenarioKind = "straight"
    # straight / obstacle road
    road_length: Positive = 120.0
    lane_width: Positive = 3.5
    num_lanes: Count = 2
    # where the ego starts: metres from the road start (straight, obstacle) or before the ring entry
    start_distance: NonNegative = 10.0
    start_speed: NonNegative = 8.0
    start_jitter_lateral: NonNegative = 0.3
    start_jitter_longitudinal: NonNegative = 1.0
    start_jitter_yaw_deg: NonNegative = 3.0
    finish_margin: NonNegative = 5.0
    # obstacle (stationary car in the ego lane, centre-to-centre distance from the nominal start)
    obstacle_distance: Positive = 40.0
    obstacle_size: tuple[Positive, Positive, Positive] = (4.5, 1.8, 1.5)
    obstacle_color: Color = (0.75, 0.1, 0.1)
    lane_change_length: Positive = 15.0
    lane_change_gap: NonNegative = 8.0
    # roundabout
    ring_radius: Positive = 14.0
    ring_width: Positive = 6.0
    arm_length: Positive = 40.0
    junction_fillet: Positive = 5.0
    route_fillet: Positive = 8.0
    island_height: Positive = 0.6
    # appearance and surroundings
    asphalt_color: Color = (0.27, 0.27, 0.29)
    marking_color: Color = (0.95, 0.95, 0.95)
    ground_color: Color = (0.30, 0.52, 0.22)
    marking_width: Positive = 0.25
    dash_length: Positive = 3.0
    dash_gap: NonNegative = 6.0
    scenery_seed: Seed = 0
    scenery_count: Seed = 40
    scenery_margin: NonNegative = 3.0
    scenery_extent: Positive = 35.0
    tree_fraction: Unit = 0.7
    trunk_color: Color = (0.40, 0.27, 0.15)
    crown_colors: tuple[Color, ...] = Field(((0.13, 0.40, 0.12), (0.20, 0.48, 0.16), (0.10, 0.33, 0.14)), min_length=1)
    building_colors: tuple[Color, ...] = Field(
        ((0.72, 0.66, 0.58), (0.58, 0.60, 0.66), (0.78, 0.52, 0.40), (0.85, 0.82, 0.72)), min_length=1
    )

    @property
    def has_obstacle(self) -> bool:
        """Whether the road has a stationary car to avoid (kind ``obstacle``)."""
        return self.kind == "obstacle"

    def __post_init__(self) -> None:
        if self.kind == "obstacle" and self.num_lanes < 2:
            raise invalid("num_lanes", self.num_lanes, "must be >= 2 for kind 'obstacle' (it passes on the left)")
        if self.kind != "roundabout" and self.start_distance + self.finish_margin >= self.road_length:
            raise invalid("start_distance", self.start_distance, f"leaves no route on a road of {self.road_length} m")
        if self.kind == "roundabout" and self.ring_width / 2 >= self.ring_radius:
            raise invalid("ring_width", self.ring_width, f"must be < 2 * ring_radius ({2 * self.ring_radius})")
        if self.kind == "roundabout" and self.start_distance >= self.arm_length:
            raise invalid("start_distance", self.start_distance, f"must be < arm_length ({self.arm_length})")


@schema
class WeatherConfig(Section):
    """Lighting (pybullet TinyRenderer) plus image-space effects of one weather condition."""

    section: ClassVar[str] = "weather"

    name: Str = "clear_noon"
    sky_top: Color = (0.30, 0.52, 0.88)
    sky_horizon: Color = (0.72, 0.83, 0.95)
    light_direction: tuple[Float, Float, Float] = (0.3, 0.2, 1.0)
    light_color: Color = (1.0, 1.0, 1.0)
    ambient: NonNegative = 0.6
    diffuse: NonNegative = 0.5
    specular: NonNegative = 0.05
    shadow: Bool = False
    brightness: Positive = 1.0
    contrast: Positive = 1.0
    tint: tuple[Positive, Positive, Positive] = (1.0, 1.0, 1.0)
    blur: NonNegative = 0.0
    road_darkening: Positive = 1.0
    road_sheen: NonNegative = 0.0
    fog_density: NonNegative = 0.0
    fog_color: Color = (0.75, 0.77, 0.80)
    rain_streaks: Seed = 0
    rain_length: NonNegative = 8.0
    rain_intensity: Unit = 0.25
    rain_angle_deg: Float = Field(10.0, ge=-80, le=80)

    def __post_init__(self) -> None:
        if not any(self.light_direction):
            raise invalid("light_direction", self.light_direction, "must not be the zero vector")


def blend_weather(start: WeatherConfig, end: WeatherConfig, t: float) -> WeatherConfig:
    """The weather a fraction ``t`` of the way from ``start`` to ``end``, so that weather can be a continuous
    condition axis (`uqdrive.envelope`): every number is interpolated, (1 − t)·start + t·end, which is each end
    exactly at t = 0 and t = 1 (colours, light, fog, blur, rain; the rain-streak count rounded to whole streaks).
    A switch (``shadow``) has no value in between: the two weathers must agree on it. The result is checked by
    the weather schema like any weather (e.g. a light direction that passes through zero is refused)."""
    t = validate(Unit, t, "weather.blend.t")
    values: dict[str, Any] = {"name": f"{start.name}~{end.name}@{t:.4g}"}
    for field in dataclasses.fields(WeatherConfig):
        a, b = getattr(start, field.name), getattr(end, field.name)
        if field.name == "name":
            continue
        if isinstance(a, bool):
            if a != b:
                raise ConfigError(
                    f"weather.blend: {start.name} and {end.name} differ in {field.name} ({a} vs {b}), "
                    "a switch with no value in between"
                )
            values[field.name] = a
        elif isinstance(a, tuple):
            values[field.name] = tuple((1 - t) * x + t * y for x, y in zip(a, b))
        elif isinstance(a, int):
            values[field.name] = round((1 - t) * a + t * b)
        else:
            values[field.name] = (1 - t) * a + t * b
    return WeatherConfig.from_config(values)


@schema
class CameraConfig(Section):
    """Front-centre camera, mounted near the windscreen and looking slightly down."""

    section: ClassVar[str] = "camera"

    # rendered size: the network's own 64x48 (it sees the grey of this image); a larger render is area-reduced to
    # 64x48 before the sensor noise (anti-aliasing at a price: 160x120 makes an env step about 4x dearer; README)
    width: Int = Field(64, ge=8)
    height: Int = Field(48, ge=8)
    fov_deg: Float = Field(60.0, gt=0, lt=180)
    mount_forward: Float = Field(0.6, ge=-5, le=5)
    mount_height: Positive = 1.4
    pitch_deg: Float = Field(-6.0, ge=-89, le=89)
    near: Positive = 0.1
    far: Positive = 150.0

    def __post_init__(self) -> None:
        if not self.far > self.near:
            raise invalid("far", self.far, f"must be > camera.near ({self.near})")


STOPPED_SPEED = 1e-6  # m/s: the car tracks a speed command of 0 exactly, so this means stopped


@schema
class VehicleConfig(Section):
    """Kinematic bicycle of a full-size car; pose refers to the body centre."""

    section: ClassVar[str] = "vehicle"

    length: Positive = 4.5
    width: Positive = 1.8
    height: Positive = 1.45
    wheelbase: Positive = 2.7
    max_steer_deg: Float = Field(35.0, gt=0, lt=90)  # steer = +1 turns the road wheels this far to the left
    steer_time_constant: NonNegative = 0.1
    max_accel: Positive = 3.0
    max_brake: Positive = 6.0
    max_speed: Positive = 20.0
    color: Color = (0.15, 0.35, 0.75)

    def __post_init__(self) -> None:
        if self.wheelbase >= self.length:
            raise invalid("wheelbase", self.wheelbase, f"must be < vehicle.length ({self.length})")


@schema
class AutopilotConfig(Section):
    """Pure pursuit on the scenario route, with optional seeded steering perturbations."""

    section: ClassVar[str] = "autopilot"

    target_speed: Positive = 8.0
    max_lateral_accel: Positive = 3.0
    min_speed: NonNegative = 3.0
    lookahead_base: Positive = 3.0
    lookahead_gain: NonNegative = 0.5
    perturb_prob: Unit = 0.0
    perturb_magnitude: Float = Field(0.15, ge=0, le=2)
    perturb_duration_s: NonNegative = 0.4


@schema
class SimConfig(Section):
    """The simulated car, its camera and the autopilot: the keys conf/sim.yaml adds to a stage's config (at its
    top level: ``section`` is empty)."""

    control_hz: Count = 15  # camera frames and control decisions per second
    horizon_s: Positive = 40  # an episode ends by timeout after this many simulated seconds
    camera: CameraConfig = Field(default_factory=CameraConfig)
    vehicle: VehicleConfig = Field(default_factory=VehicleConfig)
    autopilot: AutopilotConfig = Field(default_factory=AutopilotConfig)


@schema
class WorldAxis:
    """A condition of a Gymnasium world that a sweep varies: ``key`` under `gym_world` (e.g.
    ``env_kwargs.config.other_vehicles_type``) and its value per label, the first the world as collected; each value
    is a location of its own, named ``<gym_world.name>-<label>``."""

    key: Str
    values: Annotated[dict[Annotated[str, Field(pattern=r"^[A-Za-z0-9_.]+$")], Any], Field(min_length=1)]


@schema
class GymWorldConfig(Section):
    """A Gymnasium env as a world: ``gymnasium.make(env_id, **env_kwargs)``, read through ``hooks``.

    ``name``: the location's name in cells, files and runs (a condition of the env, e.g. other env_kwargs, is
    another location under another name).
    ``safe_if``: info key → the value it must have at every step for the path to be safe (`InfoSafeSet`).
    ``horizon_steps``: the episode ends by timeout after this many steps (T = horizon_steps / control_hz),
    or earlier if the env truncates it. ``control_hz``: decisions per simulated second (the info's ``t``).
    ``stopped_speed``: m/s at or below which a car braking for a hand-over has stopped: by default uqdrive's car's
    (it tracks 0 exactly); an env's car may approach 0 only asymptotically (HighwayEnv's, tracking a speed of 0,
    takes longer than its 15 s episode to reach 1e-6: conf/gym_world/highway_roundabout.yaml sets 0.1).
    The env's own safety signals (any hooks; ``hooks: native`` drives the env as it is, its observation and action
    the agent's own): ``unsafe_if``: info keys of which a true value at any step makes the path unsafe (checked on
    the first step: a key the env never reports is refused); ``terminated``: ``end`` (a termination ends the
    episode, judged by the other signals) or ``unsafe`` (a termination is a failure; a truncation is the end of
    time); ``safe_when``: ``module:function(obs, info) -> bool``, False at a step makes the path unsafe. The episode
    ends at the first unsafe step (termination ``unsafe``). ``observe`` (``hooks: native``): ``obs``, the env's own
    observation, or ``view``, the env's RGB rendering (uint8 [H, W, 3], ``render_mode="rgb_array"``): an image agent
    in an env whose observation is a vector.
    """

    section: ClassVar[str] = "gym_world"

    name: Annotated[str, Strict(), Field(pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")] = "gym_world"  # a file name
    env_id: Str = "uqdrive/Roundabout-v0"
    env_kwargs: dict[str, Any] = Field(default_factory=dict)
    hooks: Str = "info"  # info, highway or module:Class (`uqdrive.sim.gym_hooks`)
    hooks_options: dict[str, Any] = Field(default_factory=dict)
    safe_if: dict[str, Bool] = Field(default_factory=lambda: {"collision": False, "off_road": False})
    horizon_steps: Count = 600
    control_hz: Positive = 15.0
    stopped_speed: NonNegative = STOPPED_SPEED
    unsafe_if: list[Str] = Field(default_factory=list)
    terminated: Literal["end", "unsafe"] = "end"
    safe_when: Annotated[str, Strict(), Field(pattern=r"^([A-Za-z_][\w.]*:[A-Za-z_]\w*)?$")] = ""
    observe: Literal["obs", "view"] = "obs"
    axis: WorldAxis | None = None  # the condition its sweeps vary (safety sweep, avoid's unknown, acquire, findings)

    def __post_init__(self) -> None:
        hooks_class(self.hooks, "hooks").check_options(self.hooks_options)  # before any work: the class and options
        if self.observe == "view" and not self.native:
            raise ConfigError(f"gym_world.observe='view': applies to hooks: native, not hooks: {self.hooks!r}")

    @property
    def native(self) -> bool:
        """Whether the env is driven as it is: its own observation to the agent, the agent's action to the env."""
        return hooks_class(self.hooks).native

    def changed(self, changes: Mapping[str, Any], name: str, key: str) -> GymWorldConfig:
        """This world with each key of ``changes`` set (dotted, e.g. ``env_kwargs.config.other_vehicles_type``, or
        nested), as the location ``name``: one of the env's own conditions (``key``: where ``changes`` came from)."""
        data = self.to_dict()
        for dotted, value in _leaves(changes):
            node, last = self.condition_slot(data, dotted, f"{key}.{dotted}")
            node[last] = value
        return validate(GymWorldConfig, {**data, "name": name}, key)

    def condition_value(self, dotted: str, key: str) -> Any:
        """The value this world has at ``dotted``, a condition of its env (`condition_slot`)."""
        node, last = self.condition_slot(self.to_dict(), dotted, key)
        return node[last]

    def condition_slot(self, data: dict[str, Any], dotted: str, key: str) -> tuple[dict[str, Any], str]:
        """Where ``dotted`` sits in ``data`` (this world's config as a dict). A condition of a Gymnasium world is a
        key of its env's kwargs that the world already sets: never its rate, horizon, safe set or expert (the rollouts
        run to the world's), and never a new key (a misspelt one would be a condition identical to the known one)."""
        parts = dotted.split(".")
        if parts[0] != "env_kwargs" or len(parts) < 2:
            raise ConfigError(f"{key}: a condition of {self.env_id} is a key of its env_kwargs (env_kwargs.<key>)")
        node: Any = data
        for part in parts[:-1]:
            node = node.get(part) if isinstance(node, dict) else None
        if not isinstance(node, dict) or parts[-1] not in node:
            raise ConfigError(f"{key}: gym_world {self.name!r} sets no {dotted} (a condition changes a key it sets)")
        return node, parts[-1]


def _leaves(changes: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """(dotted key, value) of every leaf of ``changes`` (nested mappings flattened)."""
    out = []
    for k, v in changes.items():
        if isinstance(v, Mapping) and v:
            out += _leaves(v, f"{prefix}{k}.")
        else:
            out.append((f"{prefix}{k}", v))
    return out


def refuse_conditions(config: GymWorldConfig, scenario: Any, weather: Any) -> None:
    """A scenario or weather of uqdrive's (anything not None) where ``config``'s env is the world: one line naming
    the key (its value by name) and the env."""
    for key, value in (("scenario", scenario), ("weather", weather)):
        if value is not None:
            name = getattr(value, "name", value)
            raise ConfigError(f"{key}={name!r}: {config.env_id} has no {key} condition (the world is the env)")


def register_schemas() -> None:
    """The world's defaults in Hydra's ConfigStore, which conf/scenario/, conf/weather/, conf/gym_world/ and
    conf/sim.yaml extend (`scenario_schema`, `weather_schema`, `gym_world_schema`, `sim_schema`): for the stages that
    compose them. Top-level nodes, not options of the groups they fill, so `weather=weather_schema` is no weather and
    `--help` lists none."""
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    store.store(name="scenario_schema", node=defaults(ScenarioConfig))
    store.store(name="weather_schema", node=defaults(WeatherConfig))
    store.store(name="gym_world_schema", node=defaults(GymWorldConfig))
    store.store(name="sim_schema", node=defaults(SimConfig))


def check_noise(noise: float) -> float:
    """Sensor noise σ in units of full intensity (0.05 = 5 % of 255)."""
    return validate(NonNegative, noise, "noise")


def names_gym_world(name: str) -> bool:
    """Whether ``name`` is a Gymnasium world's (conf/gym_world/<name>.yaml): its experiment trains on its frames."""
    return (find_conf() / "gym_world" / f"{name}.yaml").is_file()


def _load_group_file(path: Path) -> Any:
    from omegaconf import OmegaConf

    config = OmegaConf.load(path)
    defaults = config.pop("defaults", None)
    if defaults is None:
        return config
    entries = [entry for entry in defaults if isinstance(entry, str)]  # not `override /group: …`: other groups'
    parts = [
        config if entry == "_self_" else _load_group_file(path.with_name(f"{entry}.yaml"))
        for entry in entries
        if not entry.split("@")[0].endswith("_schema")  # the schema's defaults: from_config fills them in
    ]
    if "_self_" not in entries:
        parts.append(config)
    return OmegaConf.merge(*parts)
