"""The one interface of a world the closed-loop code drives (`World`), the lane a safe set reads (`Lane`), and
the questions whose answer depends on which world it is (`WorldVisitor`).

Two worlds implement `World`: uqdrive's pybullet world (`uqdrive.sim.env.DrivingEnv`) and any Gymnasium env behind
its adapter (`uqdrive.sim.gym_world.GymWorld`). Code outside `uqdrive.sim` drives either through this interface and
never asks which one it has: what differs is a method or attribute here, and an operation of an upper layer that
differs by world (the safe set a rollout is judged by, where a failure lies) is a `WorldVisitor`, which a world
(`World.visit`) or a condition (`uqdrive.sim.condition.Condition.visit`) answers for its own kind.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

import numpy as np

from .config import AutopilotConfig, GymWorldConfig, ScenarioConfig, WeatherConfig
from .geometry import ScenarioGeometry

R = TypeVar("R", covariant=True)
Expert = Callable[[dict[str, Any]], tuple[float, float]]  # a step's info → the expert's (steering label, speed)
TRAJECTORY_KEYS = ("t", "x", "y", "yaw", "speed", "steering")


class Lane(Protocol):
    """A path on the ground in lane coordinates, as HighwayEnv's ``AbstractLane`` (``road/lane.py``) has them for
    its straight, sine and circular lanes: ``longitudinal`` metres along it, ``lateral`` metres to its left. A
    road's lane (`ScenarioGeometry`) and the path a Gymnasium run drove (`uqdrive.sim.gym_world.DrivenPath`) answer
    the same questions, so a safe set, a rollout's lateral deviation and a figure read either."""

    def position(self, longitudinal: np.ndarray, lateral: np.ndarray) -> np.ndarray:
        """The points [N, 2] at these lane coordinates."""
        ...

    def local_coordinates(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(longitudinal, lateral) of points [N, 2]."""
        ...

    def heading_at(self, longitudinal: np.ndarray) -> np.ndarray:
        """The lane's heading (rad, counter-clockwise from +x) at these longitudinal coordinates."""
        ...

    def width_at(self, longitudinal: np.ndarray) -> np.ndarray:
        """The lane's width (m) there; NaN where the world does not say."""
        ...

    def on_lane(self, points: np.ndarray) -> np.ndarray:
        """Whether each point [N, 2] lies on the lane."""
        ...


class ResetCondition(Protocol):
    """What a world is reset to (`uqdrive.sim.condition.Condition`): a location's config (a road's scenario or a
    Gymnasium world), a weather of ours (None: a Gymnasium world's, or the default) and the sensor noise σ."""

    @property
    def scenario(self) -> ScenarioConfig | GymWorldConfig: ...

    @property
    def weather(self) -> WeatherConfig | None: ...

    @property
    def noise(self) -> float: ...


class WorldVisitor(Protocol[R]):
    """An operation of an upper layer whose answer depends on the world (a safe set, a failure's placer): one method
    per world, called by the world or condition it is handed to (`World.visit`, `Condition.visit`), so that its
    caller never asks which world it has."""

    def road(self, geometry: ScenarioGeometry) -> R:
        """The answer on one of uqdrive's roads."""
        ...

    def gym(self, world: GymWorldConfig) -> R:
        """The answer in a Gymnasium world (its env is the whole world: uqdrive knows no road of it)."""
        ...


class World(abc.ABC):
    """A world one car is driven in, step by step, from a camera frame: reset to a rollout's seed and condition,
    stepped by (steer, speed) commands, judged on the lane it reports.

    An abstract base class rather than a `typing.Protocol`: the two worlds share their episode bookkeeping (``done``,
    the ``trajectory`` log, the context manager), which lives here once, and a world that forgets a method fails
    when it is made, not mid-rollout."""

    control_hz: float
    dt: float
    last_info: dict[str, Any]

    def __init__(self) -> None:
        self._done = True
        self._log: dict[str, list[float]] = {k: [] for k in TRAJECTORY_KEYS}
        self.last_info = {}

    @abc.abstractmethod
    def reset(self, seed: int, where: ResetCondition | None = None, render: bool = True) -> np.ndarray | None:
        """Start the episode of rollout seed ``seed`` at the condition ``where`` (its location, weather and sensor
        noise σ, `uqdrive.sim.condition.Condition`; None: a Gymnasium world's own, noise-free); returns the first
        frame (RGB uint8 [H, W, 3]; None when ``render`` is False)."""

    @abc.abstractmethod
    def step(self, steer: float, speed: float) -> tuple[np.ndarray | None, dict[str, Any]]:
        """Advance one control period: ``steer`` in [-1, 1] (clipped; + = left), ``speed`` the commanded m/s.
        Returns the frame and the step's info (pose, speed, collision, off_road, lateral_deviation, termination …)."""

    def apply(self, command: Any) -> tuple[Any, dict[str, Any]]:
        """Advance one control period by a policy's ``command`` (its ``steer`` and ``speed``; a world that takes the
        agent's own action, a native Gymnasium world, reads its ``env_action``)."""
        return self.step(command.steer, command.speed)

    @property
    def observation_space(self) -> Any:
        """The observation's Gymnasium space where the agent sees the env's own (None: uqdrive's camera frame)."""
        return None

    @property
    def action_space(self) -> Any:
        """The action's Gymnasium space where the agent acts in the env's own (None: a (steer, speed) command)."""
        return None

    @property
    @abc.abstractmethod
    def lane(self) -> Lane:
        """The path the current episode's safe set reads: the road's lane, or the path the run drove."""

    @property
    @abc.abstractmethod
    def stopped_speed(self) -> float:
        """m/s at or below which the car, braking for a hand-over, has stopped."""

    @property
    @abc.abstractmethod
    def car_size(self) -> tuple[float, float]:
        """The car's (length, width) in metres, which a lane rule keeps inside the lane."""

    @abc.abstractmethod
    def expert(self, autopilot: AutopilotConfig, seed: int) -> Expert:
        """The world's expert for the episode just reset (seed ``seed``): uqdrive's autopilot driving as
        ``autopilot`` says in the pybullet world, the env's own expert in a Gymnasium world."""

    @abc.abstractmethod
    def visit(self, visitor: WorldVisitor[R]) -> R:
        """``visitor``'s answer for this world at its current location."""

    def watch(self) -> None:  # noqa: B027  (a world that draws no picture of its own has nothing to switch on)
        """Draw the world's own picture at every step from now on, where it can (`view`)."""

    def view(self) -> np.ndarray | None:
        """The world's own RGB picture of the current state (not the car's camera); None where it draws none."""
        return None

    @abc.abstractmethod
    def close(self) -> None:
        """Release the world's simulator."""

    @property
    def done(self) -> bool:
        return self._done

    @property
    def trajectory(self) -> dict[str, np.ndarray]:
        """Per-step log (the paper's GPS log), including the start: t, x, y, yaw, speed, steering."""
        return {k: np.asarray(v, float) for k, v in self._log.items()}

    def _start_log(self) -> None:
        self._log = {k: [] for k in TRAJECTORY_KEYS}

    def _log_step(self, values: tuple[float, ...]) -> None:
        """One step's values of `TRAJECTORY_KEYS`, in that order."""
        for key, value in zip(TRAJECTORY_KEYS, values):
            self._log[key].append(value)

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
