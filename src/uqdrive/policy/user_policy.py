"""The one interface a user implements to have a controller certified: `DrivingPolicy`.

A policy drives one episode at a time. Each control step it receives the frame as the world renders it (RGB uint8
[H, W, 3], the camera's size) and the world's ``info`` (pose, speed, lateral deviation, progress, …: see
`uqdrive.sim.DrivingEnv.step`), and returns an `Action`: a steering command, optionally a speed, and optionally
``draws`` — n draws of its decision, class probabilities [n, C] or steering values [n] — from which η2, mutual
information and entropy are computed as for uqdrive's own Bayesian controllers. ``reset(seed)`` starts an episode:
every random number the policy draws in it must come from a generator seeded by ``seed`` (e.g.
``np.random.default_rng(seed)``), so rollout i gives the same path in any process, worker or order.

`UserPolicies` runs one instance per lockstep slot behind the rollout engine's `Policy` (slots, batched steps), so a
user's policy plugs into every executor and cell runner with no branch of its own. It checks every action (shape,
range, finiteness) and turns an exception into a `PolicyFailure` naming the policy, the seed and the step.
uqdrive's own controllers (`Controller`, `WarningController`, `AutopilotPolicy`, `ConstantPolicy`) implement that
engine `Policy` directly — batched over the slots (one trunk pass per step), and the autopilot reads the route —
and a `RolloutJob` takes either kind through its recipe (`PolicyRecipe.build`): the engine asks no policy its kind.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from uqdrive.policy.controller import Command
from uqdrive.policy.warnings import WarningActions, WarningConfig, classify
from uqdrive.schema import ConfigError
from uqdrive.uq import draw_measures

PROB_TOL = 1e-4  # rows of class-probability draws must sum to 1 within this (float32 softmax)


@dataclass(frozen=True)
class Action:
    """One decision: ``steer`` in [-1, 1] (+1 full left); ``speed`` in m/s (None: the configured cruise speed);
    ``draws``: n draws of the decision (class probabilities [n, C] over the configured steering classes, or steering
    values [n]) for η2 (the share of draws within ε of ``steer``) and, from probabilities, mutual information. For
    η̂2 to be an exact binomial mean given ``steer``, draw them apart from those that chose ``steer``."""

    steer: float
    speed: float | None = None
    draws: np.ndarray | None = None


@runtime_checkable
class DrivingPolicy(Protocol):
    """What a user implements. ``needs_camera`` (optional attribute, default True): False skips rendering."""

    def reset(self, seed: int) -> None:
        """Start an episode; seed every random draw of it from ``seed``."""

    def act(self, frame: np.ndarray | None, info: dict) -> Action:
        """The decision for this step's ``frame`` (RGB uint8 [H, W, 3]; None without a camera) and ``info``."""


class PolicyFailure(ConfigError):
    """A user policy's bad file, output or exception, in one line naming the policy (and seed and step mid-rollout):
    bad input, reported as a bad config value is (one line, exit status 2)."""


def check_action(name: str, action: Any, classes: int) -> Action:
    """``action`` as an `Action`, or a `PolicyFailure` naming ``name``, what was expected and what came back."""
    if not isinstance(action, Action):
        raise PolicyFailure(f"{name}: act() must return uqdrive.policy.user_policy.Action, got {type(action).__name__}")
    steer = action.steer
    if isinstance(steer, bool) or not isinstance(steer, (int, float, np.floating, np.integer)):
        raise PolicyFailure(f"{name}: expected a float steer in [-1, 1], got {type(steer).__name__} {steer!r}")
    if not -1.0 <= float(steer) <= 1.0:  # NaN fails too
        raise PolicyFailure(f"{name}: expected steer in [-1, 1], got {float(steer)!r}")
    speed = action.speed
    if speed is not None and not (math.isfinite(float(speed)) and float(speed) >= 0):
        raise PolicyFailure(f"{name}: expected speed >= 0 m/s or None, got {speed!r}")
    if action.draws is not None:
        _check_draws(name, np.asarray(action.draws), classes)
    return action


def _check_draws(name: str, draws: np.ndarray, classes: int) -> None:
    expected = f"draws of [n] steering in [-1, 1] or [n, {classes}] class probabilities"
    if draws.ndim == 1:
        if len(draws) and (np.isfinite(draws).all() and np.abs(draws).max() <= 1.0):
            return
    elif draws.ndim == 2 and draws.shape[1] == classes and len(draws) and np.isfinite(draws).all():
        if draws.min() >= 0 and np.abs(draws.sum(1) - 1).max() <= PROB_TOL:
            return
    got = f"shape {draws.shape}" + (f", range [{draws.min():.3g}, {draws.max():.3g}]" if draws.size else "")
    raise PolicyFailure(f"{name}: expected {expected}, got {got}")


def command_of(action: Action, centres: np.ndarray, eps: float, cruise: float) -> Command:
    """The rollout engine's command for a checked action: η2, MI and entropy from its draws (NaN without)."""
    speed = cruise if action.speed is None else float(action.speed)
    if action.draws is None:
        return Command(float(action.steer), speed)
    draws = np.asarray(action.draws, dtype=np.float64)
    decisions = draws if draws.ndim == 1 else centres[draws.argmax(1)]
    within = np.abs(decisions - float(action.steer)) <= eps + 1e-9
    mi, se, entropy = draw_measures(draws) if draws.ndim == 2 else (math.nan, math.nan, math.nan)
    return Command(
        float(action.steer),
        speed,
        eta2=float(within.mean()),
        mutual_information=mi,
        entropy=entropy,
        draws=len(draws),
        mutual_information_se=se,
        eta2_counts=(int(within.sum()),),
        mi_stages=((len(draws), mi, se),),  # one stage: the threshold calibration replays MI from it
    )


class UserWarnings:
    """The paper's warning system on a user policy's own draws: each step's level from its η̂2 and MI (`classify`:
    the fixed-n controller's rule; MI 0 for steering draws), acted on as uqdrive's warning controller acts (slow
    down, alert, hand over: brake to a stop with the wheel held). No tier guarantee is claimed: the draws are the
    policy's. One state per slot."""

    def __init__(self, config: WarningConfig, control_hz: float):
        self.config, self.hold_frames = config, round(config.hold_s * control_hz)
        self.actions: dict[int, WarningActions] = {}
        self.held: dict[int, float | None] = {}

    def reset(self, slot: int) -> None:
        self.actions[slot], self.held[slot] = WarningActions(self.config.actions, self.hold_frames), None

    def apply(self, slot: int, command: Command, info: dict) -> Command:
        c = self.config
        mi = 0.0 if math.isnan(command.mutual_information) else command.mutual_information
        level = int(classify(command.eta2, mi, c.delta1, c.delta2, c.tau))
        factor, alert, handover = self.actions[slot].step(level)
        if handover and self.held[slot] is None:
            self.held[slot] = float(info.get("steering", 0.0))
        steer = command.steer if self.held[slot] is None else self.held[slot]
        speed, handover = command.speed * float(factor), bool(handover)
        return dataclasses.replace(
            command, steer=steer, speed=speed, warning=level, alert=bool(alert), handover=handover
        )


class UserPolicies:
    """The rollout engine's `Policy` over a user's `DrivingPolicy`: one instance per slot (made by ``make``), each
    reset with its rollout's seed, stepped one frame at a time; ``centres``: the steering classes its probability
    draws are over; ``eps``: η2's ball; ``speed``: the cruise speed of an action without one; ``warnings``: acted
    on where given (every action must then carry draws)."""

    def __init__(
        self,
        name: str,
        make: Callable[[], DrivingPolicy],
        centres: np.ndarray,
        eps: float,
        speed: float,
        warnings: UserWarnings | None = None,
    ):
        self.name, self.make, self.centres = name, make, np.asarray(centres, dtype=np.float64)
        self.eps, self.speed, self.warnings = float(eps), float(speed), warnings
        self.instances: dict[int, DrivingPolicy] = {}
        self.episodes: dict[int, list[int]] = {}  # slot → [seed, step]
        self.needs_camera = True
        self.instance(0)  # made here: a policy that cannot be made fails at build, and says if it renders

    def instance(self, slot: int) -> DrivingPolicy:
        if slot not in self.instances:
            policy = self.make()
            if not callable(getattr(policy, "act", None)) or not callable(getattr(policy, "reset", None)):
                raise PolicyFailure(
                    f"{self.name}: expected a policy with reset(seed) and act(frame, info), got {type(policy).__name__}"
                )
            self.instances[slot] = policy
            self.needs_camera = bool(getattr(policy, "needs_camera", True))
        return self.instances[slot]

    def reset(self, env: Any, seed: int, slot: int = 0) -> None:
        self.episodes[slot] = [int(seed), 0]
        if self.warnings is not None:
            self.warnings.reset(slot)
        self._call(slot, "reset", lambda: self.instance(slot).reset(int(seed)))

    def act_batch(self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]) -> list:
        commands = []
        for slot, frame, info in zip(slots, frames, infos):
            action = self._call(slot, "act", lambda: self.instance(slot).act(frame, dict(info)))  # noqa: B023
            where = f"{self.name} at seed {self.episodes[slot][0]}, step {self.episodes[slot][1]}"
            command = command_of(check_action(where, action, len(self.centres)), self.centres, self.eps, self.speed)
            if self.warnings is not None:
                if action.draws is None:
                    raise PolicyFailure(f"{where}: expected draws (warnings are on), got an action without")
                command = self.warnings.apply(slot, command, info)
            commands.append(command)
            self.episodes[slot][1] += 1
        return commands

    def _call(self, slot: int, what: str, call: Callable[[], Any]) -> Any:
        """``call()``; an exception from the policy as one line with the seed and step it was raised at."""
        try:
            return call()
        except PolicyFailure:
            raise
        except Exception as err:  # the user's code: any exception is its failure
            seed, step = self.episodes.get(slot, [None, 0])
            reason = str(err).strip().splitlines()[0] if str(err).strip() else ""
            raise PolicyFailure(
                f"{self.name} raised {type(err).__name__} in {what}() at seed {seed}, step {step}"
                + (f": {reason}" if reason else "")
            ) from None
