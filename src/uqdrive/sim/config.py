"""Config schemas of the simulated world.

Every knob is a dataclass field so that a new location, weather or car is a yaml file,
not code. Validation happens in ``__post_init__`` so a bad Hydra override fails at start-up
with a message naming the key, the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from uqdrive.checks import ConfigError

SCENARIO_KINDS = ("straight", "obstacle", "roundabout")

T = TypeVar("T", bound="_Config")


def _plain(value: Any) -> Any:
    """OmegaConf containers -> plain Python, so dataclasses hold hashable, picklable values."""
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf

        if isinstance(value, (DictConfig, ListConfig)):
            return OmegaConf.to_container(value, resolve=True)
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        pass
    return value


class _Config:
    """Shared ``from_config`` and validation helpers."""

    _section: ClassVar[str] = ""

    @classmethod
    def from_config(cls: type[T], mapping: Mapping[str, Any] | None = None, **overrides: Any) -> T:
        """Build from a dict or DictConfig; unknown keys are an error, not silently dropped."""
        data = dict(_plain(mapping) or {})
        data.update(overrides)
        names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
        unknown = sorted(set(data) - names)
        if unknown:
            raise ConfigError(f"{cls._section}: unknown key(s) {unknown}; allowed keys are {sorted(names)}")
        return cls(**data)

    @classmethod
    def from_yaml(cls: type[T], path) -> T:
        """From a config-group file, honouring its Hydra ``defaults`` list of sibling files (a location
        that inherits the roundabout and changes a few fields) as ``hydra.compose`` would."""
        return cls.from_config(_load_group_file(Path(path)))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)  # type: ignore[call-overload]

    # -- validation helpers -------------------------------------------------------------
    def _key(self, name: str) -> str:
        return f"{self._section}.{name}"

    def _number(
        self,
        name: str,
        *,
        ge: float | None = None,
        gt: float | None = None,
        le: float | None = None,
        lt: float | None = None,
    ) -> None:
        value = getattr(self, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{self._key(name)}={value!r} must be a number")
        for bound, op, ok in (
            (ge, ">=", lambda b: value >= b),
            (gt, ">", lambda b: value > b),
            (le, "<=", lambda b: value <= b),
            (lt, "<", lambda b: value < b),
        ):
            if bound is not None and not ok(bound):
                raise ConfigError(f"{self._key(name)}={value!r} must be {op} {bound}")

    def _integer(self, name: str, *, ge: int) -> None:
        value = getattr(self, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < ge:
            raise ConfigError(f"{self._key(name)}={value!r} must be an integer >= {ge}")

    def _color(self, name: str) -> None:
        value = getattr(self, name)
        ok = (
            isinstance(value, Sequence)
            and not isinstance(value, str)
            and len(value) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 1.0 for v in value)
        )
        if not ok:
            raise ConfigError(f"{self._key(name)}={value!r} must be an RGB triple with components in [0, 1]")
        setattr(self, name, tuple(float(v) for v in value))

    def _colors(self, name: str) -> None:
        value = getattr(self, name)
        if isinstance(value, str) or not isinstance(value, Sequence) or len(value) == 0:
            raise ConfigError(f"{self._key(name)}={value!r} must be a non-empty list of RGB triples in [0, 1]")
        out = []
        for item in value:
            ok = (
                isinstance(item, Sequence)
                and not isinstance(item, str)
                and len(item) == 3
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 1.0 for v in item)
            )
            if not ok:
                raise ConfigError(f"{self._key(name)}={value!r} must be a non-empty list of RGB triples in [0, 1]")
            out.append(tuple(float(v) for v in item))
        setattr(self, name, tuple(out))

    def _vector(self, name: str, n: int, *, positive: bool = False) -> None:
        value = getattr(self, name)
        ok = (
            isinstance(value, Sequence)
            and not isinstance(value, str)
            and len(value) == n
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and (v > 0 or not positive) for v in value)
        )
        if not ok:
            what = "positive numbers" if positive else "numbers"
            raise ConfigError(f"{self._key(name)}={value!r} must be a list of {n} {what}")
        setattr(self, name, tuple(float(v) for v in value))


@dataclasses.dataclass
class ScenarioConfig(_Config):
    """Road layout and surroundings of one location, in metres.

    ``kind`` picks the layout; the other fields parametrise it. Straight roads run along +x
    with the right lane (right-hand traffic) at y = -lane_width / 2. Roundabouts are centred at
    the origin, the ego enters from the south arm and leaves by the first exit (east arm).
    """

    _section: ClassVar[str] = "scenario"

    name: str = "straight"
    kind: str = "straight"
    # straight / obstacle road
    road_length: float = 120.0
    lane_width: float = 3.5
    num_lanes: int = 2
    # where the ego starts: metres from the road start (straight, obstacle) or before the ring entry
    start_distance: float = 10.0
    start_speed: float = 8.0
    start_jitter_lateral: float = 0.3
    start_jitter_longitudinal: float = 1.0
    start_jitter_yaw_deg: float = 3.0
    finish_margin: float = 5.0
    # obstacle (stationary car in the ego lane, centre-to-centre distance from the nominal start)
    obstacle_distance: float = 40.0
    obstacle_size: tuple[float, float, float] = (4.5, 1.8, 1.5)
    obstacle_color: tuple[float, float, float] = (0.75, 0.1, 0.1)
    lane_change_length: float = 15.0
    lane_change_gap: float = 8.0
    # roundabout
    ring_radius: float = 14.0
    ring_width: float = 6.0
    arm_length: float = 40.0
    junction_fillet: float = 5.0
    route_fillet: float = 8.0
    island_height: float = 0.6
    # appearance and surroundings
    asphalt_color: tuple[float, float, float] = (0.27, 0.27, 0.29)
    marking_color: tuple[float, float, float] = (0.95, 0.95, 0.95)
    ground_color: tuple[float, float, float] = (0.30, 0.52, 0.22)
    marking_width: float = 0.25
    dash_length: float = 3.0
    dash_gap: float = 6.0
    scenery_seed: int = 0
    scenery_count: int = 40
    scenery_margin: float = 3.0
    scenery_extent: float = 35.0
    tree_fraction: float = 0.7
    trunk_color: tuple[float, float, float] = (0.40, 0.27, 0.15)
    crown_colors: tuple[tuple[float, float, float], ...] = ((0.13, 0.40, 0.12), (0.20, 0.48, 0.16), (0.10, 0.33, 0.14))
    building_colors: tuple[tuple[float, float, float], ...] = (
        (0.72, 0.66, 0.58),
        (0.58, 0.60, 0.66),
        (0.78, 0.52, 0.40),
        (0.85, 0.82, 0.72),
    )

    def __post_init__(self) -> None:
        if self.kind not in SCENARIO_KINDS:
            raise ConfigError(f"scenario.kind={self.kind!r} is not one of {list(SCENARIO_KINDS)}")
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError(f"scenario.name={self.name!r} must be a non-empty string")
        for name in (
            "road_length",
            "lane_width",
            "ring_radius",
            "ring_width",
            "arm_length",
            "junction_fillet",
            "route_fillet",
            "island_height",
            "marking_width",
            "dash_length",
            "lane_change_length",
            "obstacle_distance",
            "scenery_extent",
        ):
            self._number(name, gt=0)
        for name in (
            "start_distance",
            "start_speed",
            "start_jitter_lateral",
            "start_jitter_longitudinal",
            "start_jitter_yaw_deg",
            "finish_margin",
            "dash_gap",
            "lane_change_gap",
            "scenery_margin",
        ):
            self._number(name, ge=0)
        self._number("tree_fraction", ge=0, le=1)
        self._integer("num_lanes", ge=1)
        self._integer("scenery_count", ge=0)
        self._integer("scenery_seed", ge=0)
        self._vector("obstacle_size", 3, positive=True)
        for name in ("obstacle_color", "asphalt_color", "marking_color", "ground_color", "trunk_color"):
            self._color(name)
        self._colors("crown_colors")
        self._colors("building_colors")
        if self.kind == "obstacle" and self.num_lanes < 2:
            raise ConfigError(
                f"scenario.num_lanes={self.num_lanes} must be >= 2 for kind 'obstacle' (it passes on the left)"
            )
        if self.kind != "roundabout" and self.start_distance + self.finish_margin >= self.road_length:
            raise ConfigError(
                f"scenario.start_distance={self.start_distance} leaves no route on a road of length {self.road_length}"
            )
        if self.kind == "roundabout" and self.ring_width / 2 >= self.ring_radius:
            raise ConfigError(
                f"scenario.ring_width={self.ring_width} must be < 2 * ring_radius ({2 * self.ring_radius})"
            )
        if self.kind == "roundabout" and self.start_distance >= self.arm_length:
            raise ConfigError(f"scenario.start_distance={self.start_distance} must be < arm_length ({self.arm_length})")


@dataclasses.dataclass
class WeatherConfig(_Config):
    """Lighting (pybullet TinyRenderer) plus image-space effects of one weather condition."""

    _section: ClassVar[str] = "weather"

    name: str = "clear_noon"
    sky_top: tuple[float, float, float] = (0.30, 0.52, 0.88)
    sky_horizon: tuple[float, float, float] = (0.72, 0.83, 0.95)
    light_direction: tuple[float, float, float] = (0.3, 0.2, 1.0)
    light_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ambient: float = 0.6
    diffuse: float = 0.5
    specular: float = 0.05
    shadow: bool = False
    brightness: float = 1.0
    contrast: float = 1.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    blur: float = 0.0
    road_darkening: float = 1.0
    road_sheen: float = 0.0
    fog_density: float = 0.0
    fog_color: tuple[float, float, float] = (0.75, 0.77, 0.80)
    rain_streaks: int = 0
    rain_length: float = 8.0
    rain_intensity: float = 0.25
    rain_angle_deg: float = 10.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError(f"weather.name={self.name!r} must be a non-empty string")
        for name in ("sky_top", "sky_horizon", "light_color", "fog_color"):
            self._color(name)
        self._vector("tint", 3, positive=True)
        self._vector("light_direction", 3)
        if not any(self.light_direction):
            raise ConfigError(f"weather.light_direction={self.light_direction!r} must not be the zero vector")
        for name in ("ambient", "diffuse", "specular", "blur", "fog_density", "rain_length", "road_sheen"):
            self._number(name, ge=0)
        for name in ("brightness", "contrast", "road_darkening"):
            self._number(name, gt=0)
        self._number("rain_intensity", ge=0, le=1)
        self._number("rain_angle_deg", ge=-80, le=80)
        self._integer("rain_streaks", ge=0)
        if not isinstance(self.shadow, bool):
            raise ConfigError(f"weather.shadow={self.shadow!r} must be true or false")


@dataclasses.dataclass
class CameraConfig(_Config):
    """Front-centre camera, mounted near the windscreen and looking slightly down."""

    _section: ClassVar[str] = "camera"

    width: int = 64  # the network's input size (conf/sim.yaml says why)
    height: int = 48
    fov_deg: float = 60.0
    mount_forward: float = 0.6
    mount_height: float = 1.4
    pitch_deg: float = -6.0
    near: float = 0.1
    far: float = 150.0

    def __post_init__(self) -> None:
        self._integer("width", ge=8)
        self._integer("height", ge=8)
        self._number("fov_deg", gt=0, lt=180)
        self._number("mount_height", gt=0)
        self._number("mount_forward", ge=-5, le=5)
        self._number("pitch_deg", ge=-89, le=89)
        self._number("near", gt=0)
        self._number("far", gt=self.near)


@dataclasses.dataclass
class VehicleConfig(_Config):
    """Kinematic bicycle of a full-size car; pose refers to the body centre."""

    _section: ClassVar[str] = "vehicle"

    length: float = 4.5
    width: float = 1.8
    height: float = 1.45
    wheelbase: float = 2.7
    max_steer_deg: float = 35.0
    steer_time_constant: float = 0.1
    max_accel: float = 3.0
    max_brake: float = 6.0
    max_speed: float = 20.0
    color: tuple[float, float, float] = (0.15, 0.35, 0.75)

    def __post_init__(self) -> None:
        for name in ("length", "width", "height", "wheelbase", "max_accel", "max_brake", "max_speed"):
            self._number(name, gt=0)
        self._number("max_steer_deg", gt=0, lt=90)
        self._number("steer_time_constant", ge=0)
        self._color("color")
        if self.wheelbase >= self.length:
            raise ConfigError(f"vehicle.wheelbase={self.wheelbase} must be < vehicle.length ({self.length})")


@dataclasses.dataclass
class AutopilotConfig(_Config):
    """Pure pursuit on the scenario route, with optional seeded steering perturbations."""

    _section: ClassVar[str] = "autopilot"

    target_speed: float = 8.0
    max_lateral_accel: float = 3.0
    min_speed: float = 3.0
    lookahead_base: float = 3.0
    lookahead_gain: float = 0.5
    perturb_prob: float = 0.0
    perturb_magnitude: float = 0.15
    perturb_duration_s: float = 0.4

    def __post_init__(self) -> None:
        for name in ("target_speed", "max_lateral_accel", "lookahead_base"):
            self._number(name, gt=0)
        for name in ("lookahead_gain", "perturb_duration_s", "min_speed"):
            self._number(name, ge=0)
        self._number("perturb_prob", ge=0, le=1)
        self._number("perturb_magnitude", ge=0, le=2)


def check_noise(noise: float) -> float:
    """Sensor noise sigma in units of full intensity (0.05 = 5 % of 255)."""
    if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not noise >= 0:
        raise ConfigError(f"noise={noise!r} must be >= 0")
    return float(noise)


def _load_group_file(path: Path) -> Any:
    from omegaconf import OmegaConf

    config = OmegaConf.load(path)
    defaults = config.pop("defaults", None)
    if defaults is None:
        return config
    parts = [config if entry == "_self_" else _load_group_file(path.with_name(f"{entry}.yaml")) for entry in defaults]
    if "_self_" not in defaults:
        parts.append(config)
    return OmegaConf.merge(*parts)
