"""One closed-loop episode: seed → start jitter, weather effects, sensor noise and posterior draws → verdict.

Everything random in rollout i comes from its seed (``base_seed + i``), so a rollout gives
the same result in any process, with any backend, in any order. A policy that hands control
to the operator (``Command.handover``) brakes to a stop; the rollout then ends with termination
``handover`` and is judged by the safe set like any other path.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uqdrive.safety.controller import Policy
from uqdrive.safety.safe_sets import HANDOVER, SafeSet, safe_set_for
from uqdrive.sim import DrivingEnv, ScenarioConfig, WeatherConfig

STOPPED_SPEED = 1e-6  # m/s: the car tracks a speed command of 0 exactly, so this means stopped


def _empty() -> np.ndarray:
    return np.zeros(0)


@dataclass(frozen=True)
class RolloutResult:
    """Outcome of one episode; ``x``, ``y`` are the body-centre positions at every control step
    (and the last pose). Per-decision traces (one value per step): ``eta2``, ``mutual_information``,
    ``warning`` (level, -1 for none) and ``command_speed``."""

    seed: int
    safe: bool
    termination: str
    collision: bool
    off_road: bool
    left_corridor: bool
    reached_goal: bool
    corridor_use: float
    mean_abs_lateral_deviation: float
    mean_eta2: float
    mean_mutual_information: float
    steps: int
    x: np.ndarray
    y: np.ndarray
    eta2: np.ndarray = field(default_factory=_empty)
    mutual_information: np.ndarray = field(default_factory=_empty)
    warning: np.ndarray = field(default_factory=_empty)
    command_speed: np.ndarray = field(default_factory=_empty)

    def summary(self) -> dict:
        """The scalar fields (one row of the per-rollout table)."""
        return {k: v for k, v in self.__dict__.items() if not isinstance(v, np.ndarray)}


def run_rollout(
    env: DrivingEnv,
    policy: Policy,
    seed: int,
    scenario: ScenarioConfig,
    weather: WeatherConfig,
    noise: float,
    half_width: float | None = None,
    safe_set: SafeSet | None = None,
) -> RolloutResult:
    """Drive one episode until the env ends it (collision, off road, route complete or horizon T)
    or the policy has handed over and the car has stopped.

    The episode runs to its end even after the car leaves the corridor, so collision and
    off-road rates and the visited positions describe the whole path.
    """
    obs = env.reset(seed, scenario, weather, noise, render=policy.needs_camera)
    policy.reset(env, seed)
    safe_set = safe_set or safe_set_for(env.geometry, env.vehicle_config.width, env.vehicle_config.length, half_width)
    info = env.last_info
    termination = info["termination"]
    commands = []
    while not env.done:
        command = policy.act(obs, info)
        commands.append(command)
        obs, info = env.step(command.steer, command.speed)
        termination = info["termination"]
        if not termination and command.handover and info["speed"] <= STOPPED_SPEED:
            termination = HANDOVER
            break
    eta2 = [c.eta2 for c in commands]
    mi = [c.mutual_information for c in commands]
    log = env.trajectory
    verdict = safe_set.judge(env.geometry, log["x"], log["y"], log["yaw"], termination)
    lateral = env.geometry.lateral_deviation(np.stack([log["x"], log["y"]], axis=1))
    return RolloutResult(
        seed=seed,
        safe=verdict.safe,
        termination=termination,
        collision=verdict.collision,
        off_road=verdict.off_road,
        left_corridor=verdict.left_corridor,
        reached_goal=verdict.reached_goal,
        corridor_use=verdict.corridor_use,
        mean_abs_lateral_deviation=float(np.mean(np.abs(lateral))),
        mean_eta2=float(np.mean(eta2)) if eta2 else float("nan"),
        mean_mutual_information=float(np.mean(mi)) if mi else float("nan"),
        steps=len(commands),
        x=log["x"],
        y=log["y"],
        eta2=np.array(eta2, dtype=float),
        mutual_information=np.array(mi, dtype=float),
        warning=np.array([c.warning for c in commands], dtype=np.int8),
        command_speed=np.array([c.speed for c in commands], dtype=float),
    )
