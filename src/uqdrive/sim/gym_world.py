"""Any registered Gymnasium env as a world the closed-loop rollouts drive.

`GymWorld` is a `uqdrive.sim.world.World`, as `DrivingEnv` is, so `run_rollouts` drives it as it drives the pybullet
world; its lane is the path the run drove (`DrivenPath`), judged by `uqdrive.safety.info_safe_set.InfoSafeSet` (a
predicate over every step's info).

What differs between envs sits behind the world's hooks (``GymWorldConfig.hooks``, `uqdrive.sim.gym_hooks`): how
the env's observation becomes the network's grey frame, where pose, speed, collision and off-road come from, how a
(steer, speed) command becomes the env's action, and what the env's own expert would do. ``info`` reads them from
the env's info dict (an env written for uqdrive, e.g. `uqdrive.sim.gym_env`); ``highway`` reads HighwayEnv's ego
vehicle (`uqdrive.sim.gym_highway`, the one module that names that package); ``module:Class`` is anyone's. An
exception from the env's or the hooks' code is one line with the seed and step (`WorldFailure`).

Frames are delivered as uqdrive's camera delivers them: RGB uint8 [48, 64, 3], here with three equal channels (the
grey frame), so `preprocess_frame` gives the grey frame back exactly; sensor noise (σ in units of full intensity)
is the camera's own `add_noise`, seeded by the rollout seed. A condition the env does not have (a scenario, a
weather) is refused, never ignored.

In a rollout's `uqdrive.sim.condition.Condition` a Gymnasium world is the location (its ``scenario``), with no
weather: ``Condition(GymWorldConfig(...), None, noise)``. A world resets to the config it is handed, remaking its env
when the config differs (as `DrivingEnv` rebuilds its world for another scenario).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any, TypeVar

import cv2
import numpy as np

from uqdrive.network_input import INPUT_HEIGHT, INPUT_WIDTH
from uqdrive.schema import ConfigError

from .camera import add_noise
from .config import AutopilotConfig, GymWorldConfig, VehicleConfig, check_noise, refuse_conditions
from .gym_hooks import HOOKS, WorldFailure, WorldHooks, hooks_class
from .gym_native import in_space, predicate, short
from .world import TRAJECTORY_KEYS, Expert, R, ResetCondition, World, WorldVisitor

Returned = TypeVar("Returned")


@dataclass
class DrivenPath:
    """The lane of a Gymnasium run (`uqdrive.sim.world.Lane`): uqdrive knows no road of the env, so the path the
    car drove stands in for it, with what the env reported at every step (its info, the reset's first). It answers
    at the path's own points, one per recorded step: lane coordinates are the metres driven and the env's lateral
    deviation, on the lane is not off the road, the heading is the car's, the width the env does not say."""

    infos: list[dict[str, Any]] = field(default_factory=list)

    def _driven(self) -> np.ndarray:
        """Metres driven up to each recorded step."""
        x, y = (np.array([info[k] for info in self.infos], dtype=float) for k in ("x", "y"))
        return np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])

    def _per_step(self, points: np.ndarray, key: str) -> np.ndarray:
        """The recorded ``key`` at the path's points (one per step, as the trajectory logs them)."""
        if len(points) != len(self.infos):
            raise ValueError(f"{len(points)} points for an episode of {len(self.infos)} recorded steps")
        return np.array([info[key] for info in self.infos], dtype=float)

    def position(self, longitudinal: np.ndarray, lateral: np.ndarray) -> np.ndarray:
        driven = self._driven()
        x, y = (np.interp(longitudinal, driven, [info[k] for info in self.infos]) for k in ("x", "y"))
        heading = self.heading_at(longitudinal)
        return np.stack([x - lateral * np.sin(heading), y + lateral * np.cos(heading)], axis=-1)

    def local_coordinates(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._driven()[: len(points)], self._per_step(points, "lateral_deviation")

    def heading_at(self, longitudinal: np.ndarray) -> np.ndarray:
        yaw = np.unwrap([info["yaw"] for info in self.infos])
        return np.interp(longitudinal, self._driven(), yaw)

    def width_at(self, longitudinal: np.ndarray) -> np.ndarray:
        return np.full(np.shape(longitudinal), np.nan)

    def on_lane(self, points: np.ndarray) -> np.ndarray:
        return self._per_step(points, "off_road") == 0


class GymWorld(World):
    """A Gymnasium env driven as uqdrive drives `DrivingEnv` (module docstring). Episode ends: ``collision`` and
    ``off_road`` (from the hooks' state, as `DrivingEnv` ends them), ``terminated`` (the env ended it otherwise),
    ``timeout`` (``horizon_steps``, or the env truncated it)."""

    def __init__(self, config: GymWorldConfig):
        super().__init__()
        self._make(config)
        self.noise = 0.0
        self.render_enabled = True
        self._noise_rng = np.random.default_rng(0)
        self._steps = 0
        self._applied = 0.0
        self._path = DrivenPath()

    def _make(self, config: GymWorldConfig) -> None:
        """The env of ``config`` and its hooks (the config's control rate and horizon with them)."""
        gymnasium = _gymnasium()
        hooks_cls = hooks_class(config.hooks)
        self.config, self._seed = config, None  # no episode of this env yet (a failure here says so)
        kwargs = self._user("hooks", "env_kwargs", hooks_cls.env_kwargs, config.env_kwargs)
        if config.observe == "view":
            kwargs = {**kwargs, "render_mode": "rgb_array"}
        self._view_space: Any = None
        try:
            env = gymnasium.make(config.env_id, **kwargs)
        except gymnasium.error.Error as err:
            raise ConfigError(f"gym_world.env_id={config.env_id!r}: {err}") from None
        self.env = env
        self.hooks: WorldHooks = self._user("hooks", "__init__", hooks_cls, env, config)
        self.safe_when = predicate(config.safe_when)
        self.control_hz = float(config.control_hz)
        self.dt = 1.0 / self.control_hz

    def reset(self, seed: int, where: ResetCondition | None = None, render: bool = True) -> np.ndarray | None:
        """Start the episode of rollout seed ``seed`` (the env's ``reset(seed=seed)``; the sensor noise drawn from
        the same seed); returns the first frame (None when ``render`` is False). ``where``: a condition in this world
        (its `GymWorldConfig`: the env is remade if it differs from the current one; its noise) or None (the current
        world, noise-free); any other scenario, and any weather, is refused: the env is its own world, and has no
        weather."""
        scenario, weather, noise = (None, None, 0.0) if where is None else (where.scenario, where.weather, where.noise)
        world = scenario if isinstance(scenario, GymWorldConfig) else self.config
        refuse_conditions(world, None if scenario is world else scenario, weather)
        if world != self.config or type(self.hooks) is not hooks_class(world.hooks):  # or its code was reloaded
            self.env.close()
            self._make(world)
        self.noise = check_noise(noise)
        if self.noise and self.hooks.native:
            raise ConfigError(f"noise={noise!r}: {world.env_id} is driven as it is (hooks: native), with no camera")
        self.render_enabled = bool(render) or self.hooks.native
        self._seed, self._steps, self._applied, self._done = int(seed), 0, 0.0, False
        obs, env_info = self._user("env_id", "reset", self.env.reset, seed=int(seed))
        self._noise_rng = np.random.default_rng(np.random.SeedSequence(int(seed)))
        self._user("hooks", "begin", self.hooks.begin)
        self._path = DrivenPath()
        self._start_log()
        self._record(obs, env_info, terminated=False, truncated=False)
        return self._frame(obs)

    def step(self, steer: float, speed: float) -> tuple[np.ndarray | None, dict[str, Any]]:
        """Advance one control period: steer in [-1, 1] (clipped; + = left), speed in m/s."""
        if self._done:
            raise RuntimeError("episode is over (or was never started); call reset() first")
        self._applied = min(max(float(steer), -1.0), 1.0)
        action = self._user("hooks", "action", self.hooks.action, self._applied, float(speed))
        obs, _, terminated, truncated, env_info = self._user("env_id", "step", self.env.step, action)
        self._steps += 1
        info = self._record(obs, env_info, bool(terminated), bool(truncated))
        return self._frame(obs), info

    def apply(self, command: Any) -> tuple[Any, dict[str, Any]]:
        """A command's (steer, speed), or, driven as it is (hooks: native), its ``env_action``: in the env's action
        space (an action outside it is one line with the seed and step, before the env sees it)."""
        if not self.hooks.native:
            return self.step(command.steer, command.speed)
        if self._done:
            raise RuntimeError("episode is over (or was never started); call reset() first")
        given, space = getattr(command, "env_action", None), self.env.action_space
        action = in_space(given, space)
        if action is None:
            raise WorldFailure(
                f"{self.config.env_id} at seed {self._seed}, step {self._steps}: the agent's action {short(given)} "
                f"is outside the env's action space {space}"
            )
        self._applied = math.nan
        obs, _, terminated, truncated, env_info = self._user("env_id", "step", self.env.step, action)
        self._steps += 1
        return self._frame(obs), self._record(obs, env_info, bool(terminated), bool(truncated))

    @property
    def observation_space(self) -> Any:
        """What a native agent observes: the env's observation space, or its rendering's (``observe: view``, known
        from the first reset on)."""
        if not self.hooks.native:
            return None
        return self._view_space if self.config.observe == "view" else self.env.observation_space

    @property
    def action_space(self) -> Any:
        return self.env.action_space if self.hooks.native else None

    def expert_command(self) -> tuple[float, float]:
        """(steer, speed) the env's own expert would command in the current state (a collect stage's label)."""
        return self._user("hooks", "expert", self.hooks.expert)

    def _user(self, key: str, what: str, call: Callable[..., Returned], *args: Any, **kwargs: Any) -> Returned:
        """``call(*args, **kwargs)`` of the env's or the hooks' code (``key``: which config key names it); any
        exception but a config error as one `WorldFailure` line with the seed and step it was raised at."""
        try:
            return call(*args, **kwargs)
        except ConfigError:
            raise
        except Exception as err:  # the user's code: any exception is its failure
            where = f"at seed {self._seed}, step {self._steps}" if self._seed is not None else "before any episode"
            text = str(err).strip().splitlines()
            raise WorldFailure(
                f"gym_world.{key}={getattr(self.config, key)!r} raised {type(err).__name__} in {what}() {where}"
                + (f": {text[0][:200]}" if text else "")
            ) from None

    def _record(self, obs: Any, env_info: Mapping[str, Any], terminated: bool, truncated: bool) -> dict[str, Any]:
        state = self._user("hooks", "state", self.hooks.state, env_info)
        unsafe = self._unsafe(obs, env_info, terminated)
        if unsafe:
            termination = "unsafe"
        elif state["collision"]:
            termination = "collision"
        elif state["off_road"]:
            termination = "off_road"
        elif terminated:
            termination = "terminated"
        elif truncated or self._steps >= self.config.horizon_steps:
            termination = "timeout"
        else:
            termination = ""
        self._done = termination != ""
        own, env = {k: _plain(v) for k, v in state.items()}, _scalars(env_info)
        info = {**own, **env} if self.hooks.native else {**env, **own}  # native: the env's own keys win
        info.update(t=self._steps * self.dt, steering=self._applied, done=self._done, termination=termination)
        info.update(unsafe=bool(unsafe), unsafe_because=unsafe)
        missing = [key for key in self.config.safe_if if key not in info]
        if missing:
            raise ConfigError(
                f"gym_world.safe_if: {missing[0]!r} is not in the info of {self.config.env_id!r} "
                f"(it has {sorted(info)})"
            )
        self._log_step(tuple(float(info[key]) for key in TRAJECTORY_KEYS))
        self._path.infos.append(info)
        self.last_info = info
        return info

    def _unsafe(self, obs: Any, env_info: Mapping[str, Any], terminated: bool) -> str:
        """Why this step is unsafe by the env's own signals (``unsafe_if``, ``safe_when``, ``terminated``), "" if
        it is not. An ``unsafe_if`` key the env's info lacks at its first step is refused, listing the keys it has."""
        config = self.config
        if self._steps == 1 and (missing := [k for k in config.unsafe_if if k not in env_info]):
            raise ConfigError(
                f"gym_world.unsafe_if: {missing[0]!r} is not in the info of {config.env_id!r} at its first step "
                f"(it reports {sorted(env_info)})"
            )
        for key in config.unsafe_if:
            if bool(env_info.get(key, False)):
                return key
        if self.safe_when is not None:
            name = config.safe_when.partition(":")[2]
            verdict = self._user("safe_when", name, self.safe_when, obs, dict(env_info))
            if not isinstance(verdict, (bool, np.bool_)):
                raise WorldFailure(f"gym_world.safe_when={config.safe_when!r}: expected a bool, got {short(verdict)}")
            if not verdict:
                return "safe_when"
        return "terminated" if terminated and config.terminated == "unsafe" else ""

    def _frame(self, obs: Any) -> Any:
        if self.hooks.native:
            return obs if self.config.observe == "obs" else self._rendered()
        if not self.render_enabled:
            return None
        grey = self._user("hooks", "frame", self.hooks.frame, obs)
        if grey.shape != (INPUT_HEIGHT, INPUT_WIDTH):
            grey = cv2.resize(grey, (INPUT_WIDTH, INPUT_HEIGHT), interpolation=cv2.INTER_AREA)
        if self.noise == 0:
            return cv2.merge((grey, grey, grey))
        rgb = cv2.merge((grey, grey, grey)).astype(np.float32)
        rgb *= np.float32(1 / 255)
        return add_noise(rgb, self.noise, self._noise_rng)

    @property
    def lane(self) -> DrivenPath:
        """The path the current episode drove, with every step's info: what its safe set judges."""
        return self._path

    @property
    def stopped_speed(self) -> float:
        """The env's car's own (``GymWorldConfig.stopped_speed``): it may approach 0 only asymptotically."""
        return self.config.stopped_speed

    @property
    def car_size(self) -> tuple[float, float]:
        """uqdrive's default car's: the env's car is the env's, and no lane rule of ours reads it."""
        car = VehicleConfig()
        return car.length, car.width

    def expert(self, autopilot: AutopilotConfig, seed: int) -> Expert:
        """The env's own expert (`expert_command`), whatever the step's info: it reads the env's state."""
        return lambda info: self.expert_command()

    def visit(self, visitor: WorldVisitor[R]) -> R:
        return visitor.gym(self.config)

    def watch(self) -> None:
        """Ask an env that can draw itself (``rgb_array``) to: rendering reads the env's state and changes none of
        it (a re-driven rollout's path is checked unchanged)."""
        inner = self.env.unwrapped
        if getattr(inner, "render_mode", None) is None and "rgb_array" in inner.metadata.get("render_modes", []):
            inner.render_mode = "rgb_array"

    def view(self) -> np.ndarray | None:
        """The env's own RGB picture of the current state (None: an env that draws none)."""
        if getattr(self.env, "render_mode", None) != "rgb_array":
            return None
        image = self.env.render()
        return np.asarray(image) if isinstance(image, np.ndarray) and image.ndim == 3 else None

    def _rendered(self) -> np.ndarray:
        """The env's RGB rendering as a native agent observes it (``observe: view``), with the space it lies in."""
        image = self.view()
        if image is None:
            raise ConfigError(f"gym_world.observe='view': {self.config.env_id} renders no RGB image (rgb_array)")
        image = np.ascontiguousarray(image, dtype=np.uint8)
        if self._view_space is None or self._view_space.shape != image.shape:
            self._view_space = _gymnasium().spaces.Box(0, 255, image.shape, np.uint8)
        return image

    def close(self) -> None:
        self.env.close()


def world_identity(config: GymWorldConfig) -> dict[str, Any]:
    """What a Gymnasium world's rollouts depend on beyond code, for a cell's identity hash: the config (env id,
    kwargs, hooks, safe set, horizon) and the versions of Gymnasium, of the env's and the hooks' distributions and of
    what they name (e.g. the renderer that draws HighwayEnv's observation). The code it loads by name, a user's
    included, is digested with every other module of the cell (`world_modules`)."""
    found = metadata.packages_distributions()
    owners = {name for module in _world_modules(config) for name in found.get(module.partition(".")[0], [])}
    names = sorted({"gymnasium", *owners, *hooks_class(config.hooks).packages})
    own = {k: v for k, v in config.to_dict().items() if k != "axis"}  # what its sweeps vary: not a rollout's
    return {"config": own, "packages": {name: metadata.version(name) for name in names}}


def world_modules(config: GymWorldConfig) -> list[str]:
    """The modules a Gymnasium world's rollouts run that no static import reaches (its hooks and env are loaded by
    name), uqdrive's and a user's, for a cell's code digest."""
    return list(dict.fromkeys(["uqdrive.sim.gym_world", *_world_modules(config)]))


def _world_modules(config: GymWorldConfig) -> list[str]:
    """The modules a world loads by name: its hooks', the one its env id names (``module:Id``) and its env's."""
    named = config.env_id.rpartition(":")[0]
    hooks = HOOKS.get(config.hooks, config.hooks).partition(":")[0]
    judge = config.safe_when.partition(":")[0]  # a user's predicate: its source is in the cell's identity
    return [m for m in dict.fromkeys([hooks, named, _entry_module(config), judge]) if m]


def _entry_module(config: GymWorldConfig) -> str:
    """The module that defines the env ``config.env_id`` names (``module:Id-v0``, as `gymnasium.make` takes it: the
    module registers the id when imported, in a worker process too)."""
    hooks_class(config.hooks)  # first: importing the hooks registers their package's env ids
    gymnasium = _gymnasium()
    module, _, env_id = config.env_id.rpartition(":")
    try:
        if module:
            importlib.import_module(module)
        entry = gymnasium.spec(env_id).entry_point
    except (ImportError, gymnasium.error.Error) as err:
        raise ConfigError(f"gym_world.env_id={config.env_id!r}: {err}") from None
    return entry.split(":")[0] if isinstance(entry, str) else entry.__module__


def _gymnasium() -> Any:
    """Gymnasium, with uqdrive's own ids registered (importing `uqdrive.sim.gym_env` registers them)."""
    import gymnasium

    from . import gym_env  # noqa: F401

    return gymnasium


def _scalars(info: Mapping[str, Any]) -> dict[str, Any]:
    """The env's own info, less what is not a scalar (arrays, nested dicts): the safe set reads scalars."""
    return {k: _plain(v) for k, v in info.items() if isinstance(v, (bool, int, float, str, np.generic))}


def _plain(value: Any) -> Any:
    """numpy scalars as Python's (True is True, not np.True_)."""
    return value.item() if isinstance(value, np.generic) else value
