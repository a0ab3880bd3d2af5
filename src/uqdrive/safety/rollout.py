"""One closed-loop episode: seed → start jitter, weather effects, sensor noise and posterior draws → verdict.

Everything random in rollout i comes from its seed (``base_seed + i``), so a rollout gives
the same result in any process, with any backend, in any order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uqdrive.safety.controller import Policy
from uqdrive.safety.safe_sets import SafeSet, safe_set_for
from uqdrive.sim import DrivingEnv, ScenarioConfig, WeatherConfig


@dataclass(frozen=True)
class RolloutResult:
    """Outcome of one episode; ``x``, ``y`` are the body-centre positions at every control step."""

    seed: int
    safe: bool
    termination: str
    collision: bool
    off_road: bool
    left_corridor: bool
    reached_exit: bool
    mean_abs_lateral_deviation: float
    mean_eta2: float
    mean_mutual_information: float
    steps: int
    x: np.ndarray
    y: np.ndarray

    def summary(self) -> dict:
        """The scalar fields (one row of the per-rollout table)."""
        return {k: v for k, v in self.__dict__.items() if k not in ("x", "y")}


def run_rollout(env: DrivingEnv, policy: Policy, seed: int, scenario: ScenarioConfig, weather: WeatherConfig,
                noise: float, half_width: float | None = None, safe_set: SafeSet | None = None) -> RolloutResult:
    """Drive one episode until the env ends it (collision, off road, route complete or horizon T).

    The episode runs to its end even after the car leaves the corridor, so collision and
    off-road rates and the visited positions describe the whole path.
    """
    obs = env.reset(seed, scenario, weather, noise, render=policy.needs_camera)
    policy.reset(env, seed)
    safe_set = safe_set or safe_set_for(env.geometry, half_width)
    info = env.last_info
    eta2, mi = [], []
    while not env.done:
        command = policy.act(obs, info)
        eta2.append(command.eta2)
        mi.append(command.mutual_information)
        obs, info = env.step(command.steer, command.speed)
    log = env.trajectory
    verdict = safe_set.judge(env.geometry, log["x"], log["y"], info["termination"])
    lateral = env.geometry.lateral_deviation(np.stack([log["x"], log["y"]], axis=1))
    return RolloutResult(seed=seed, safe=verdict.safe, termination=info["termination"], collision=verdict.collision,
                         off_road=verdict.off_road, left_corridor=verdict.left_corridor,
                         reached_exit=verdict.reached_exit,
                         mean_abs_lateral_deviation=float(np.mean(np.abs(lateral))),
                         mean_eta2=float(np.mean(eta2)) if eta2 else float("nan"),
                         mean_mutual_information=float(np.mean(mi)) if mi else float("nan"),
                         steps=len(eta2), x=log["x"], y=log["y"])
