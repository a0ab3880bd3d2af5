"""The paper's three-tier warning system on real-time decision confidence η2 (Definition 2) and mutual information.

Each frame falls in one of four levels: no warning (η2 ≥ δ1 and MI ≤ τ), warning 0 (η2 ≥ δ1
but MI > τ), warning 1 (δ2 ≤ η2 < δ1) and warning 2 (η2 < δ2). Each level has a configurable
action: a speed as a fraction of the cruise speed, an alert to the operator, and a hand-over
(brake to a stop and give control to the operator; once fired it holds until the car stops).
The classification and the actions are vectorised over a batch, so the live controller (a
batch of one) and the threshold calibration (a batch of candidate thresholds × rollouts) run
the same code.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from uqdrive.data.binning import SteeringBins
from uqdrive.models.posterior import Posterior
from uqdrive.safety.controller import NO_WARNING, Command, Controller
from uqdrive.safety.draws import DrawSettings, FrameDecision
from uqdrive.schema import Bool, NonNegative, OpenUnit, Unit, defaults, invalid, schema, validate
from uqdrive.uq import chernoff_n
from uqdrive.uq.tier import DOUBTFUL, UNSURE, TierTest

LEVELS = (0, 1, 2)


@schema(frozen=True)
class WarningAction:
    """What one warning level does: drive at ``speed`` × the cruise speed, alert the operator, hand over
    (brake to a stop and give control to the operator, so it needs ``speed`` = 0)."""

    speed: Unit
    alert: Bool = False
    handover: Bool = False

    def __post_init__(self) -> None:
        if self.handover and self.speed != 0:
            raise invalid("speed", self.speed, "must be 0 when handover is true (a hand-over brakes to a stop)")


@schema(frozen=True)
class WarningLevels:
    """One action per level, iterated in level order 0, 1, 2: the paper's slow down; slow down and alert;
    brake to a stop and hand over."""

    warning0: WarningAction = WarningAction(0.5)  # high mutual information
    warning1: WarningAction = WarningAction(0.5, alert=True)  # not δ1-confident
    warning2: WarningAction = WarningAction(0.0, alert=True, handover=True)  # not δ2-confident

    def __iter__(self) -> Iterator[WarningAction]:
        return iter((self.warning0, self.warning1, self.warning2))

    def __len__(self) -> int:
        return len(LEVELS)

    def __getitem__(self, level: int) -> WarningAction:
        return tuple(self)[level]


@schema(frozen=True)
class WarningConfig:
    """Thresholds (δ1, δ2 on η2; τ on MI in nats), actions per level, and the per-frame sample size.

    ``theta``, ``gamma``: each frame draws ``chernoff_n(theta, gamma)`` weight samples, so the
    estimated η2 is within θ of the true η2 with probability ≥ 1 − γ (738 at 0.05/0.05).
    ``hold_s``: a slow-down lasts this long after the last frame that asked for it.
    """

    delta1: Unit = 0.7
    delta2: Unit = 0.6  # <= delta1: warning 2 (η2 < δ2) is the severe one
    tau: NonNegative = 0.45  # nats of mutual information
    theta: OpenUnit = 0.05
    gamma: OpenUnit = 0.05
    hold_s: NonNegative = 1.0
    actions: WarningLevels = WarningLevels()

    def __post_init__(self) -> None:
        if self.delta2 > self.delta1:
            raise invalid(
                "delta2", self.delta2, f"must be <= delta1={self.delta1!r} (warning 2, η2 < δ2, is the severe one)"
            )

    @classmethod
    def from_config(cls, mapping: Mapping[str, Any]) -> WarningConfig:
        """From the `warning` config group; ``actions`` maps warning0/1/2 to speed, alert, handover."""
        return validate(cls, mapping, "warning")

    @property
    def samples(self) -> int:
        """Weight samples per frame: Chernoff's n for (θ, γ)."""
        return chernoff_n(self.theta, self.gamma)

    def with_thresholds(self, delta1: float, delta2: float, tau: float) -> WarningConfig:
        return dataclasses.replace(self, delta1=float(delta1), delta2=float(delta2), tau=float(tau))

    def to_dict(self) -> dict:
        """Plain values (for hashes, JSON and MLflow)."""
        return {
            "delta1": self.delta1,
            "delta2": self.delta2,
            "tau": self.tau,
            "theta": self.theta,
            "gamma": self.gamma,
            "hold_s": self.hold_s,
            "samples": self.samples,
            "actions": {
                f"warning{level}": {"speed": a.speed, "alert": a.alert, "handover": a.handover}
                for level, a in zip(LEVELS, self.actions)
            },
        }


def register_schema() -> None:
    """The warning system's defaults (the paper's) in Hydra's ConfigStore as `warning_schema`, which
    conf/warning/*.yaml extend."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(name="warning_schema", node=defaults(WarningConfig))


def classify(
    eta2: np.ndarray | float,
    mutual_information: np.ndarray | float,
    delta1: np.ndarray | float,
    delta2: np.ndarray | float,
    tau: np.ndarray | float,
) -> np.ndarray:
    """Warning level per frame (NO_WARNING, 0, 1 or 2); every argument broadcasts against the others.

    η2 < δ2 → 2; δ2 ≤ η2 < δ1 → 1; η2 ≥ δ1 and MI > τ → 0; otherwise no warning.
    """
    eta2, mi = np.asarray(eta2, dtype=float), np.asarray(mutual_information, dtype=float)
    if not (np.isfinite(eta2).all() and np.isfinite(mi).all()):
        raise ValueError("eta2 and mutual_information must be finite (a Bayesian controller's measures)")
    return np.where(eta2 < delta2, 2, np.where(eta2 < delta1, 1, np.where(mi > tau, 0, NO_WARNING))).astype(np.int8)


def warning_level(tier: int, mutual_information: float, tau: float) -> int:
    """One frame's level from its η2 tier (`uqdrive.safety.draws`: decided by the frame's draws) and its MI: what
    `classify` gives from η2 itself."""
    if tier == DOUBTFUL:
        return 2
    if tier == UNSURE:
        return 1
    return 0 if mutual_information > tau else NO_WARNING


class WarningActions:
    """The actions' state over a batch of systems: slow-downs held ``hold_frames``, hand-over latched.

    ``step(levels)`` takes this frame's levels (any shape, fixed per instance) and returns the
    speed factor, whether an alert is raised, and whether a hand-over is under way.
    """

    def __init__(self, actions: tuple[WarningAction, ...], hold_frames: int, shape: tuple[int, ...] = ()):
        self.speeds = np.array([a.speed for a in actions])
        self.alerts = np.array([a.alert for a in actions])
        self.handovers = np.array([a.handover for a in actions])
        self.hold_frames = int(hold_frames)
        self.remaining = np.zeros((len(actions), *shape), dtype=np.int64)  # frames each level's slow-down lasts
        self.handover = np.zeros(shape, dtype=bool)

    def step(self, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        levels = np.asarray(levels)
        fired = levels[None] == np.arange(len(self.speeds)).reshape(-1, *([1] * levels.ndim))
        self.remaining = np.where(fired, self.hold_frames + 1, np.maximum(self.remaining - 1, 0))
        self.handover |= (fired & self.handovers.reshape(-1, *([1] * levels.ndim))).any(0)
        active = self.remaining > 0
        factor = np.where(active, self.speeds.reshape(-1, *([1] * levels.ndim)), 1.0).min(0)
        alert = (fired & self.alerts.reshape(-1, *([1] * levels.ndim))).any(0)
        return np.where(self.handover, 0.0, factor), alert | self.handover, self.handover.copy()


class WarningController(Controller):
    """The Bayesian controller with the warning system: π(o) steers, the warning level sets the speed.

    OutcomeStream ``config.samples`` weight samples per frame (Chernoff's n for the config's θ, γ).
    A hand-over brakes with the steering wheel held where it was when it fired (the network is
    not trusted any more), at speed 0 with ``handover`` set; the rollout ends once the car has stopped.
    Each lockstep slot keeps its own actions' state.
    """

    def __init__(
        self,
        posterior: Posterior,
        bins: SteeringBins,
        config: WarningConfig,
        eps: float,
        speed: float,
        control_hz: float,
        draws: DrawSettings | None = None,
    ):
        super().__init__(posterior, bins, config.samples, eps, speed, draws)
        self.config = config
        if self.draws.scheme == "sequential":
            self.tier = TierTest(
                config.delta1, config.delta2, self.draws.gamma, self.draws.theta, self.draws.look, self.n_samples
            )
        self.hold_frames = round(config.hold_s * control_hz)
        self.actions = {0: WarningActions(config.actions, self.hold_frames)}
        self.held_steer: dict[int, float | None] = {0: None}

    def reset(self, env, seed: int, slot: int = 0) -> None:
        super().reset(env, seed, slot)
        self.actions[slot] = WarningActions(self.config.actions, self.hold_frames)
        self.held_steer[slot] = None

    @property
    def thresholds(self) -> tuple[float, float]:
        return self.config.delta1, self.config.delta2

    @property
    def tau(self) -> float:
        return self.config.tau

    def commands(self, slots: Sequence[int], frames: Sequence[FrameDecision], infos: Sequence[dict]) -> list[Command]:
        """π(o) steers, the frame's warning level sets the speed (and may hand over)."""
        commands = super().commands(slots, frames, infos)
        levels = [warning_level(f.tier, f.mutual_information, self.config.tau) for f in frames]
        return [self._act_on(*args) for args in zip(slots, commands, levels, infos)]

    def _act_on(self, slot: int, command: Command, level: int, info: dict) -> Command:
        factor, alert, handover = self.actions[slot].step(level)
        if handover and self.held_steer[slot] is None:
            self.held_steer[slot] = float(info.get("steering", 0.0))
        held = self.held_steer[slot]
        return dataclasses.replace(
            command,
            steer=command.steer if held is None else held,
            speed=self.speed * float(factor),
            warning=level,
            alert=bool(alert),
            handover=bool(handover),
        )
