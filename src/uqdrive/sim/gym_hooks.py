"""What one family of Gymnasium envs needs to be a uqdrive world: its hooks, a `WorldHooks` subclass that
``gym_world.hooks`` names — ``info`` and ``highway`` (uqdrive's), or ``module:Class`` (anyone's).

The hooks say how the env's observation becomes the network's grey frame, where pose, speed, collision and off-road
come from (the safe set reads them), how a (steer, speed) command becomes the env's action, and, optionally, what
the env's own expert would do (what labels a collection's frames; a world without one can still be certified).
The class is looked up and its ``hooks_options`` checked when the world's config is validated, before any work.
"""

from __future__ import annotations

import abc
import importlib
import inspect
from collections.abc import Mapping
from typing import Any, ClassVar

import cv2
import numpy as np

from uqdrive.schema import ConfigError

STATE_KEYS = ("x", "y", "yaw", "speed", "collision", "off_road", "lateral_deviation")
HOOKS = {
    "info": "uqdrive.sim.gym_hooks:InfoHooks",
    "highway": "uqdrive.sim.gym_highway:HighwayHooks",
    "native": "uqdrive.sim.gym_hooks:NativeHooks",
}
EXTRAS = {"highway": "highway"}  # uqdrive's hooks whose package is an optional extra: `pip install 'uqdrive[...]'`


class WorldFailure(ConfigError):
    """An exception from a world's own code (its env or hooks) mid-episode, in one line naming the config key, the
    method, the seed and the step: a user's bug, not uqdrive's, so no traceback (the stage exits 2)."""


class WorldHooks(abc.ABC):
    """A family of Gymnasium envs behind `uqdrive.sim.gym_world.GymWorld`; ``cls(env, config)`` is made with each
    env (the gym_world config; raise `ConfigError` there for an env these hooks cannot read).

    Define `frame`, `state` and `action`; optionally ``OPTIONS`` (the keys ``hooks_options`` may set, with their
    defaults; `check_options` for their values), ``packages`` (distributions whose versions a cell's identity
    records), `env_kwargs`, `begin` and `expert`. Poses are in uqdrive's frame: x, y in metres with y to the left
    of x, yaw counter-clockwise, lateral deviation + = left; steer + = left, in [-1, 1]."""

    OPTIONS: ClassVar[Mapping[str, Any]] = {}
    packages: ClassVar[tuple[str, ...]] = ()
    native: ClassVar[bool] = False  # True: the env's observation and action pass as they are (`NativeHooks`)

    def __init__(self, env: Any, config: Any):
        self.env, self.env_id = env, config.env_id
        self.options = {**self.OPTIONS, **config.hooks_options}

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """Refuse, in one line naming the key (relative to gym_world), an option these hooks do not know; a
        subclass that checks values too raises `uqdrive.schema.invalid` (a ValueError) likewise."""
        for key, value in options.items():
            if key not in cls.OPTIONS:
                known = ", ".join(cls.OPTIONS) or "none"
                raise ValueError(f"hooks_options.{key}={value!r}: not an option of {cls.__name__} (known: {known})")

    @classmethod
    def env_kwargs(cls, kwargs: Mapping[str, Any]) -> dict[str, Any]:
        """``gymnasium.make``'s kwargs from the config's (e.g. yaml lists to the tuples an env expects)."""
        return dict(kwargs)

    def begin(self) -> None:  # noqa: B027  (optional: most hooks keep no per-episode state)
        """A new episode has started (the env is reset)."""

    @abc.abstractmethod
    def frame(self, obs: Any) -> np.ndarray:
        """The env's observation as a grey uint8 image [H, W] (resized to the network's 64x48 if it is not)."""

    @abc.abstractmethod
    def state(self, info: Mapping[str, Any]) -> dict[str, Any]:
        """`STATE_KEYS` (and any other keys the safe set may read) after a reset or step; ``info``: the env's."""

    @abc.abstractmethod
    def action(self, steer: float, speed: float) -> Any:
        """The env's action for a steering command and a commanded speed (m/s)."""

    def expert(self) -> tuple[float, float]:
        """(steer, speed) the env's own expert would command now; hooks without one never label frames."""
        raise ConfigError(f"{type(self).__name__}: {self.env_id} has no expert")


class InfoHooks(WorldHooks):
    """An env whose info carries `STATE_KEYS` in uqdrive's frame and whose observation is a grey [H, W] or RGB
    [H, W, 3] uint8 image; its action is [steer] (speed: the env's own) or [steer, speed]. No expert."""

    def __init__(self, env: Any, config: Any):
        super().__init__(env, config)
        shape = getattr(env.action_space, "shape", None)
        if shape not in ((1,), (2,)):
            raise ConfigError(
                f"gym_world.env_id={config.env_id!r}: action space {env.action_space} is not [steer] or [steer, speed]"
            )
        self.action_size, self.dtype = shape[0], env.action_space.dtype

    def frame(self, obs: Any) -> np.ndarray:
        image = np.asarray(obs)
        if image.dtype != np.uint8 or not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
            raise ValueError(f"{self.env_id}: observation {image.dtype} {image.shape} is not a uint8 grey or RGB image")
        return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)

    def state(self, info: Mapping[str, Any]) -> dict[str, Any]:
        missing = [key for key in STATE_KEYS if key not in info]
        if missing:
            raise ConfigError(
                f"gym_world.hooks='info': the info of {self.env_id!r} has no {missing[0]!r} (it has {sorted(info)})"
            )
        return {key: info[key] for key in STATE_KEYS}

    def action(self, steer: float, speed: float) -> np.ndarray:
        return np.array([steer, speed][: self.action_size], dtype=self.dtype)


class NativeHooks(WorldHooks):
    """The env as it is (``hooks: native``): the agent observes what the env returns and acts in its action space
    (the world passes both through: `frame` and `action` are never asked). uqdrive knows no pose of the env: the
    state is NaN, with no collision or off-road of its own; the env's own signals (``unsafe_if``, ``terminated``,
    ``safe_when``) make a path unsafe."""

    native = True

    def frame(self, obs: Any) -> np.ndarray:
        raise ConfigError(f"gym_world.hooks='native': {self.env_id}'s observation is the agent's own, not a frame")

    def state(self, info: Mapping[str, Any]) -> dict[str, Any]:
        nan = float("nan")
        return {"x": nan, "y": nan, "yaw": nan, "speed": nan, "lateral_deviation": nan, "collision": 0, "off_road": 0}

    def action(self, steer: float, speed: float) -> Any:
        raise ConfigError(f"gym_world.hooks='native': {self.env_id} takes the agent's own action, not a steer")


def hooks_class(name: str, key: str = "gym_world.hooks") -> type[WorldHooks]:
    """The hooks class ``name`` names (one of `HOOKS`, or ``module:Class``), or one `ConfigError` line naming
    ``key``, the value and what is allowed."""
    module, sep, attr = HOOKS.get(name, name).partition(":")
    names = ", ".join(list(HOOKS)[:-1]) + f" or {list(HOOKS)[-1]}"
    allowed = f"expected {names}, or module:Class (a subclass of uqdrive.sim.gym_hooks.WorldHooks)"
    if not (sep and module and attr.isidentifier()):
        raise ConfigError(f"{key}={name!r}: {allowed}")
    try:
        cls = getattr(importlib.import_module(module), attr)
    except ImportError as err:
        extra = f": pip install 'uqdrive[{EXTRAS[name]}]'" if name in EXTRAS else ""
        raise ConfigError(f"{key}={name!r} needs {err.name!r}{extra}") from None
    except AttributeError:
        raise ConfigError(f"{key}={name!r}: module {module} has no {attr}") from None
    if not (inspect.isclass(cls) and issubclass(cls, WorldHooks)):
        raise ConfigError(f"{key}={name!r}: {allowed}, got {cls!r}")
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(cls.__abstractmethods__))
        raise ConfigError(f"{key}={name!r}: {cls.__name__} does not define {missing} (WorldHooks)")
    return cls


def require_expert(name: str, env_id: str) -> None:
    """Refuse, in one line, hooks that know no expert (what labels a collection's frames)."""
    if hooks_class(name).expert is WorldHooks.expert:
        raise ConfigError(
            f"gym_world.hooks={name!r}: {env_id} has no expert these hooks know of, so no frames to label; "
            "collect in a world whose hooks define expert() (WorldHooks), e.g. hooks: highway"
        )
