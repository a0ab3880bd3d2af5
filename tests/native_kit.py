"""Tiny Gymnasium envs and agents for the native-agent tests (`uqdrive certify --env native_kit:ID`): importing this
module registers the envs, so a worker process that imports it by the env id's ``module:`` has them too; and
`plain_outcomes`, the per-seed outcomes a plain Gymnasium loop gives, to compare uqdrive's rollouts with."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

WALK, SLIDE, SLOW, PICTURE = "NativeKitWalk-v0", "NativeKitSlide-v0", "NativeKitSlow-v0", "NativeKitPicture-v0"


class WalkEnv(gymnasium.Env):
    """A walker on a line: Dict observation (position, which way the wind blows), Discrete(3) actions (left, stay,
    right), a random drift; info ``fell`` once |position| >= 3 (the env terminates there)."""

    def __init__(self, drift: float = 0.6):
        self.observation_space = spaces.Dict(
            {"pos": spaces.Box(-5.0, 5.0, (1,), np.float32), "wind": spaces.Discrete(2)}
        )
        self.action_space = spaces.Discrete(3)
        self.drift, self.pos, self.wind = drift, 0.0, 0

    def _obs(self) -> dict[str, Any]:
        return {"pos": np.array([self.pos], np.float32), "wind": self.wind}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.pos, self.wind = float(self.np_random.uniform(-1.5, 1.5)), int(self.np_random.integers(2))
        return self._obs(), {"fell": False}

    def step(self, action):
        wind = 0.3 if self.wind else -0.3
        self.pos = float(
            np.clip(self.pos + (int(action) - 1) * 0.5 + wind + self.np_random.normal(0, self.drift), -5, 5)
        )
        fell = abs(self.pos) >= 3.0
        return self._obs(), -abs(self.pos), fell, False, {"fell": fell}


class SlideEnv(gymnasium.Env):
    """A puck on a line: Box(2) observation (position, velocity), Box(1) action in [-1, 1] (a push); info ``off``
    once |position| > 1 (it does not terminate: the safe set reads the key)."""

    def __init__(self):
        self.observation_space = spaces.Box(-np.inf, np.inf, (2,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.x = self.v = 0.0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.x, self.v = (float(u) for u in self.np_random.uniform(-0.6, 0.6, 2))
        return np.array([self.x, self.v], np.float32), {"off": False}

    def step(self, action):
        self.v = 0.9 * self.v + 0.1 * float(np.asarray(action).reshape(-1)[0]) + float(self.np_random.normal(0, 0.05))
        self.x += 0.2 * self.v
        return np.array([self.x, self.v], np.float32), 0.0, False, False, {"off": abs(self.x) > 1.0}


class SlowEnv(WalkEnv):
    """`WalkEnv` whose steps take ``delay`` seconds for seeds below ``slow_below`` (a worker given those finishes
    last), writing the time each episode ends (it falls, or its 20 steps are up) to ``log_dir``: the order the
    workers finished in."""

    def __init__(self, delay: float = 0.0, slow_below: int = 0, log_dir: str = ""):
        super().__init__()
        self.delay, self.slow_below, self.log_dir, self.seed, self.steps = delay, slow_below, log_dir, 0, 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.seed, self.steps = int(seed or 0), 0
        return super().reset(seed=seed, options=options)

    def step(self, action):
        if self.seed < self.slow_below:
            time.sleep(self.delay)
        out = super().step(action)
        self.steps += 1
        if (out[2] or self.steps == 20) and self.log_dir:
            Path(self.log_dir, f"{self.seed}").write_text(repr(time.monotonic()))
        return out


class PictureEnv(WalkEnv):
    """`WalkEnv` seen as an image: RGB uint8 [36, 36, 3] (the smallest stable-baselines3's CnnPolicy takes), the
    walker a bright column where it stands."""

    def __init__(self):
        super().__init__()
        self.observation_space = spaces.Box(0, 255, (36, 36, 3), np.uint8)

    def _obs(self) -> np.ndarray:
        image = np.zeros((36, 36, 3), np.uint8)
        column = int(np.clip(round((self.pos + 3.0) / 6.0 * 35), 0, 35))
        image[:, column, :] = 255 if self.wind else 128
        return image


gymnasium.register(WALK, entry_point=WalkEnv, max_episode_steps=20)
gymnasium.register(PICTURE, entry_point=PictureEnv, max_episode_steps=20)
gymnasium.register(SLIDE, entry_point=SlideEnv, max_episode_steps=25)
gymnasium.register(SLOW, entry_point=SlowEnv, max_episode_steps=20)


def toward_centre(obs: dict[str, Any]) -> int:
    """A plain function agent of `WalkEnv`: step toward 0."""
    pos = float(obs["pos"][0])
    return 0 if pos > 0.5 else 2 if pos < -0.5 else 1


class Hesitant:
    """`toward_centre` with draws: 8 rows of action probabilities from its own seeded generator, each leaning to the
    action it took (so η̂2 is high but not 1), for η2 and mutual information."""

    def reset(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, obs: dict[str, Any], info: dict) -> Any:
        from uqdrive.policy.interface import Action

        action = toward_centre(obs)
        return Action(env_action=action, draws=self.draws(action))

    def draws(self, action: int) -> np.ndarray:
        return 0.7 * self.rng.dirichlet(np.ones(3), 8) + 0.3 * np.eye(3)[action]


def push(obs: np.ndarray) -> int:
    """A plain function agent of CartPole: push toward where the pole leans."""
    return int(obs[2] > 0)


def stays_near(obs: Any, info: dict) -> bool:
    """A predicate (safe_when): the walker within 2 of the centre."""
    return abs(float(obs["pos"][0])) < 2.0


def raises(obs: Any, info: dict) -> bool:
    raise ZeroDivisionError("the predicate's own bug")


def plain_outcomes(
    env_id: str,
    act: Callable[[Any], Any],
    seeds: range,
    unsafe: Callable[[Any, dict, bool], bool],
    steps: int = 1000,
    view: bool = False,
    **kwargs: Any,
) -> str:
    """'1' (safe) or '0' per seed by a plain Gymnasium loop: reset with the seed, act until the env ends the episode
    or ``steps``; unsafe if ``unsafe(obs, info, terminated)`` holds at any step (the reset's included). ``view``: the
    agent acts on the env's RGB rendering instead of its observation."""
    out = []
    with gymnasium.make(env_id, **kwargs, **({"render_mode": "rgb_array"} if view else {})) as env:
        for seed in seeds:
            obs, info = env.reset(seed=seed)
            safe, done, n = not unsafe(obs, info, False), False, 0
            while safe and not done and n < steps:
                obs, _, terminated, truncated, info = env.step(act(env.render() if view else obs))
                safe, done, n = not unsafe(obs, info, terminated), terminated or truncated, n + 1
            out.append("1" if safe else "0")
    return "".join(out)


def lean_from_picture(image: Any) -> int:
    """An image agent: push toward the side the pole leans to, read off the rendered RGB frame alone (CartPole draws
    its pole in tan: the top row of those pixels against the bottom one)."""
    pole = (image[..., 0] > 150) & (image[..., 1] > 100) & (image[..., 1] < 180) & (image[..., 2] < 120)
    rows = np.nonzero(pole.any(axis=1))[0]
    if not len(rows):
        return 0
    return int(np.nonzero(pole[rows[0]])[0].mean() > np.nonzero(pole[rows[-1]])[0].mean())
