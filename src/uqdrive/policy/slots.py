"""Running a policy that decides one frame at a time in lockstep slots: `PolicySlots`, one instance per slot.

`PolicySlots` is the lockstep fast path (`uqdrive.policy.interface`) of a policy without one of its own — a user's,
or uqdrive's `ConstantPolicy` — so such a policy plugs into every executor and cell runner with no branch of its own.
It checks every action (shape, range, finiteness), reads its draws into η2, mutual information and entropy
(`command_of`), acts on the warning system where configured (`UserWarnings`), and turns an exception into a
`PolicyFailure` naming the policy, the seed and the step. `in_lockstep` gives the engine any policy in lockstep: the
policy itself where it steps slots at once, else `PolicySlots` of copies of it.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from uqdrive.data.binning import SteeringBins
from uqdrive.policy.interface import Action, Command, LockstepPolicy, Policy
from uqdrive.policy.warnings import WarningActions, WarningConfig, classify
from uqdrive.schema import ConfigError
from uqdrive.uq import draw_measures

PROB_TOL = 1e-4  # rows of class-probability draws must sum to 1 within this (float32 softmax)
CRUISE_SPEED = 6.0  # m/s of an action that gives none, unless its policy's settings say otherwise
EPS = 0.1  # η2's ball (steering units), unless its policy's settings say otherwise


class PolicyFailure(ConfigError):
    """A user policy's bad file, output or exception, in one line naming the policy (and seed and step mid-rollout):
    bad input, reported as a bad config value is (one line, exit status 2)."""


def check_action(name: str, action: Any, classes: int) -> Action:
    """``action`` as an `Action`, or a `PolicyFailure` naming ``name``, what was expected and what came back."""
    if not isinstance(action, Action):
        raise PolicyFailure(f"{name}: act() must return uqdrive.policy.interface.Action, got {type(action).__name__}")
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
    """The rollout engine's command for a checked action: η2, MI and entropy from its draws (NaN without); a
    `Command` (measured by its policy) as it is."""
    if isinstance(action, Command):
        return action
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
        draw_count=len(draws),
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


class PolicySlots(LockstepPolicy):
    """A policy without a lockstep fast path, in lockstep: one instance per slot (made by ``make``), each reset with
    its rollout's seed, stepped one frame at a time; ``name``: what its errors call it; ``centres``: the steering
    classes its probability draws are over; ``eps``: η2's ball; ``speed``: the cruise speed of an action without
    one; ``warnings``: acted on where given (every action must then carry draws)."""

    def __init__(
        self,
        name: str,
        make: Callable[[], Policy],
        centres: np.ndarray | None = None,
        eps: float = EPS,
        speed: float = CRUISE_SPEED,
        warnings: UserWarnings | None = None,
    ):
        centres = SteeringBins().centres if centres is None else centres
        self.name, self.make, self.centres = name, make, np.asarray(centres, dtype=np.float64)
        self.eps, self.speed, self.warnings = float(eps), float(speed), warnings
        self.instances: dict[int, Policy] = {}
        self.episodes: dict[int, list[int]] = {}  # slot → [seed, step]
        self.needs_camera = True
        self.instance(0)  # made here: a policy that cannot be made fails at build, and says if it renders

    def instance(self, slot: int) -> Policy:
        if slot not in self.instances:
            policy = self.make()
            if not callable(getattr(policy, "act", None)) or not callable(getattr(policy, "reset", None)):
                raise PolicyFailure(
                    f"{self.name}: expected a policy with reset(seed) and act(frame, info), got {type(policy).__name__}"
                )
            self.instances[slot] = policy
            self.needs_camera = bool(getattr(policy, "needs_camera", True))
        return self.instances[slot]

    def reset(self, seed: int, slot: int = 0, world: Any = None) -> None:
        self.episodes[slot] = [int(seed), 0]
        if self.warnings is not None:
            self.warnings.reset(slot)
        self._call(slot, "reset", lambda: self.instance(slot).reset(int(seed)))

    def act_batch(
        self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]
    ) -> list[Command]:
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
        return guarded(self.name, self.episodes.get(slot, [None, 0]), what, call)


def guarded(name: str, episode: Sequence[Any], what: str, call: Callable[[], Any]) -> Any:
    """``call()`` of a user's policy ``name`` in its ``episode`` ([seed, step]); an exception as one
    `PolicyFailure` line with the seed and step it was raised at."""
    try:
        return call()
    except PolicyFailure:
        raise
    except Exception as err:  # the user's code: any exception is its failure
        seed, step = episode
        reason = str(err).strip().splitlines()[0] if str(err).strip() else ""
        raise PolicyFailure(
            f"{name} raised {type(err).__name__} in {what}() at seed {seed}, step {step}"
            + (f": {reason}" if reason else "")
        ) from None


def in_lockstep(policy: Policy) -> LockstepPolicy:
    """``policy`` as the engine drives it: itself where it has the lockstep fast path (``act_batch``), else
    `PolicySlots` of copies of it as given (each slot's reset seeds its copy's episode)."""
    if callable(getattr(policy, "act_batch", None)):
        return policy
    template = copy.deepcopy(policy)
    return PolicySlots(type(policy).__name__, lambda: copy.deepcopy(template))
