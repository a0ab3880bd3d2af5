"""The one interface everything that drives implements — uqdrive's Bayesian controllers, its reference policies and a
user's policy alike: `Policy` (``reset(seed)``, ``act(frame, info) -> Action``), and the decisions it returns.

A policy drives one episode at a time. Each control step it receives the frame as the world renders it (RGB uint8
[H, W, 3], the camera's size; None where it reads no camera) and the world's ``info`` (pose, speed, lateral
deviation, progress, …: see `uqdrive.sim.DrivingEnv.step`), and returns an `Action`: a steering command, optionally a
speed, and optionally ``draws`` — n draws of its decision, class probabilities [n, C] or steering values [n] — from
which η2, mutual information and entropy are computed as for uqdrive's own controllers. A policy that measures its
uncertainty itself returns a `Command` (an `Action` with its measures read): uqdrive's controllers do.

The rollout engine asks no policy what it is. It drives a policy through its optional lockstep fast path where the
policy has one — ``act_batch(slots, frames, infos)``, several episodes' steps at once (one network pass), each slot's
episode started by ``reset(seed, slot=slot, world=world)`` — and otherwise through `uqdrive.policy.slots.PolicySlots`,
one instance per slot, each reset and asked one frame at a time.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

NO_WARNING = -1
"""Warning level of a frame that raised none (levels 0, 1, 2: see `uqdrive.policy.warnings`)."""


@dataclass(frozen=True)
class Action:
    """One decision: ``steer`` in [-1, 1] (+1 full left); ``speed`` in m/s (None: the configured cruise speed);
    ``draws``: n draws of the decision (class probabilities [n, C] over the configured steering classes, or steering
    values [n]) for η2 (the share of draws within ε of ``steer``) and, from probabilities, mutual information. For
    η̂2 to be an exact binomial mean given ``steer``, draw them apart from those that chose ``steer``.
    ``env_action``: an agent's action in the env's own action space, where the world takes it as it is (a native
    Gymnasium world, `uqdrive.policy.native`; ``steer`` is then NaN): an int of a Discrete, an array of a Box."""

    steer: float = math.nan
    speed: float | None = None
    draws: np.ndarray | None = None
    env_action: Any = None


@dataclass(frozen=True)
class Command(Action):
    """A decision with its measures read, as a rollout records it: from an `Action`'s draws
    (`uqdrive.policy.slots.command_of`), or by the policy itself (uqdrive's controllers, from their posterior draws);
    the uncertainty fields are NaN for a policy without draws. ``warning``, ``alert``, ``handover``: set by a policy
    with the warning system; with ``handover`` the car brakes to a stop and the rollout ends there (control goes to
    the operator)."""

    eta2: float = math.nan
    mutual_information: float = math.nan
    entropy: float = math.nan
    warning: int = NO_WARNING
    alert: bool = False
    handover: bool = False
    draw_count: int = 0  # draws the decision read
    mutual_information_se: float = math.nan  # jackknife standard error of the MI at those draws
    eta2_counts: tuple[int, ...] = ()  # successes at each look of the frame's η2 stream read (`FrameDecision`)
    mi_stages: tuple[tuple[int, float, float], ...] = ()  # (draws, MI, SE) at each stage of π(o)'s draws read


class Policy(Protocol):
    """What drives. ``needs_camera`` (optional attribute, default True): False skips rendering. Optional lockstep
    fast path, used where present: ``act_batch(slots, frames, infos) -> list[Command]``, with ``reset(seed,
    slot=slot, world=world)`` starting each slot's episode (the module's docstring)."""

    def reset(self, seed: int) -> None:
        """Start an episode; seed every random draw of it from ``seed``, so it gives the same path anywhere."""

    def act(self, frame: np.ndarray | None, info: dict) -> Action:
        """The decision for this step's ``frame`` (RGB uint8 [H, W, 3]; None without a camera) and ``info``."""


class LockstepPolicy(ABC):
    """A policy with the lockstep fast path: ``act_batch`` decides the current frame of several slots' episodes at
    once, and `act` is that on slot 0. A world-reading policy (the expert) takes its world at ``reset``."""

    needs_camera = True

    @abstractmethod
    def reset(self, seed: int, slot: int = 0, world: Any = None) -> None:
        """Start the episode in ``slot`` (``world`` already reset); every random draw of it from ``seed``."""

    @abstractmethod
    def act_batch(
        self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]
    ) -> list[Command]:
        """Commands for the current frame and state of each of ``slots``."""

    def act(self, frame: np.ndarray | None, info: dict | None = None) -> Command:
        """The command for one frame, in slot 0."""
        return self.act_batch([0], [frame], [info or {}])[0]
