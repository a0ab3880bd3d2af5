"""Reference policies whose safety is known, so that the safe sets and cells can be checked against them: the world's
expert (η1 ≈ 1) and a fixed steer (full left: η1 ≈ 0)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from uqdrive.policy.interface import Action, Command, LockstepPolicy
from uqdrive.sim import AutopilotConfig
from uqdrive.sim.world import Expert, World


class ExpertPolicy(LockstepPolicy):
    """The world's expert, the one that produced the training data: the pure-pursuit autopilot with ``config`` (its
    perturbations off: it drives with its own label) in the pybullet world, the env's own expert in a Gymnasium
    world. It reads the world's route, so it takes the world at ``reset``. Its η̂1 is the reference line of a safe
    set's check and of an acquisition's check cells."""

    needs_camera = False

    def __init__(self, config: AutopilotConfig | None = None):
        self.config = dataclasses.replace(config or AutopilotConfig(), perturb_prob=0.0)
        self._experts: dict[int, Expert] = {}

    def reset(self, seed: int, slot: int = 0, world: World | None = None) -> None:
        if world is None:
            raise ValueError("the expert drives by the world's route: reset(seed, world=the world just reset)")
        self._experts[slot] = world.expert(self.config, seed)

    def command(self, slot: int, info: dict) -> tuple[float, float]:
        """(steering label, speed) the expert commands in the state of ``info``."""
        return self._experts[slot](info)

    def act_batch(
        self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]
    ) -> list[Command]:
        return [Command(*self.command(slot, info)) for slot, info in zip(slots, infos)]


class ConstantPolicy:
    """Fixed steering and speed (full left = +1: a reference of η1 ≈ 0)."""

    needs_camera = False

    def __init__(self, steer: float, speed: float):
        self.steer, self.speed = float(steer), float(speed)

    def reset(self, seed: int) -> None:
        """Nothing random to seed."""

    def act(self, frame: np.ndarray | None, info: dict) -> Action:
        return Action(self.steer, self.speed)
