"""The paper's three-tier warning system on real-time decision confidence η2 (Definition 2) and mutual information.

Each frame falls in one of four levels: no warning (η2 ≥ δ1 and MI ≤ τ), warning 0 (η2 ≥ δ1
but MI > τ), warning 1 (δ2 ≤ η2 < δ1) and warning 2 (η2 < δ2). Each level has a configurable
action: a speed as a fraction of the cruise speed, an alert to the operator, and a hand-over
(brake to a stop and give control to the operator; once fired it holds until the car stops).
The classification and the actions are vectorised over a batch, so the live controller (a
batch of one) and the threshold calibration (a batch of candidate thresholds × rollouts) run
the same code. `WarningRule` is the deployed rule as one object — thresholds, the tier rule that
decides η2's tier from a frame's draws, the actions — which the controller acts by and the
calibration replays.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from uqdrive.data.binning import SteeringBins
from uqdrive.models.posterior import Posterior
from uqdrive.policy.controller import Controller
from uqdrive.policy.draws import DrawSettings, FrameDecision, first_draws, refined_mutual_information
from uqdrive.policy.interface import NO_WARNING, Command
from uqdrive.schema import Bool, ConfigError, NonNegative, OpenUnit, Unit, defaults, invalid, schema, validate
from uqdrive.uq import chernoff_n
from uqdrive.uq.tier import DOUBTFUL, UNSURE, TierRule, tier_rule

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


def levels_of(tiers: np.ndarray | int, mutual_information: np.ndarray | float, tau: np.ndarray | float) -> np.ndarray:
    """Warning levels from η2 tiers (decided by a tier rule from the frames' draws) and MI, broadcast: what
    `classify` gives from η2 itself — DOUBTFUL → 2, UNSURE → 1, confident with MI > τ → 0, else none."""
    tiers, mi = np.asarray(tiers), np.asarray(mutual_information, dtype=float)
    return np.where(tiers == DOUBTFUL, 2, np.where(tiers == UNSURE, 1, np.where(mi > tau, 0, NO_WARNING))).astype(
        np.int8
    )


@dataclasses.dataclass(frozen=True)
class WarningRule:
    """The warning rule a controller deploys: thresholds, actions and hold (``config``) and how a frame's η2 tier is
    decided from its draws (``draws``: `TierTest` for sequential draws, `FixedTier` for the paper's fixed ones,
    built once, its exact wrong-tier error checked against γ). The warning controller acts by it and the
    threshold calibration replays it on recorded η2 streams: one object, so the rule certified is the rule
    deployed. Raises `ConfigError` (one line naming the settings and the error) for a tier rule above γ."""

    config: WarningConfig
    draws: DrawSettings

    def __post_init__(self) -> None:
        object.__setattr__(self, "tier", self._tier_rule())

    def _tier_rule(self) -> TierRule:
        c, d = self.config, self.draws
        theta, gamma, keys = d.method.tier_accuracy(d, c.theta, c.gamma)
        try:
            return tier_rule(d.method.tier_kind, c.delta1, c.delta2, gamma, theta, first_draws(d, c.samples), c.samples)
        except ValueError as err:
            raise ConfigError(
                f"warning.delta1={c.delta1!r}, warning.delta2={c.delta2!r}: {err} (set by {keys}; its cap by "
                "warning.theta, warning.gamma)"
            ) from None

    @property
    def cap(self) -> int:
        """η2 draws per frame at most (Chernoff's n for the warning config's θ, γ)."""
        return self.config.samples

    @property
    def looks(self) -> tuple[int, ...]:
        return self.tier.looks

    def with_thresholds(self, delta1: float, delta2: float, tau: float) -> WarningRule:
        """The same rule (tier settings, actions, hold) at other thresholds."""
        return WarningRule(self.config.with_thresholds(delta1, delta2, tau), self.draws)

    def levels(self, eta2_counts: np.ndarray, mi_stages: np.ndarray) -> np.ndarray:
        """Warning levels of recorded frames (η2 counts [..., looks], MI stages [..., S, 3]): what the controller
        raises on the same draws."""
        tau = self.config.tau
        return levels_of(self.tier.tiers(eta2_counts), refined_mutual_information(mi_stages, tau), tau)

    def describe(self) -> str:
        """The rule in words, for certificates and reports."""
        c, t = self.config, self.tier
        middle = "guaranteed" if t.middle_guaranteed else "not guaranteed (delta1 - delta2 < 2 theta)"
        actions = "; ".join(
            f"warning{level} speed {a.speed:g}"
            + (" + alert" if a.alert else "")
            + (" + hand-over" if a.handover else "")
            for level, a in zip(LEVELS, c.actions)
        )
        return (
            f"delta1={c.delta1:g}, delta2={c.delta2:g}, tau={c.tau:g} nats; {t.scheme} tier rule theta={t.theta:g}, "
            f"gamma={t.gamma:g}, looks {'/'.join(map(str, t.looks))} (exact wrong-tier error {t.error:.4f}; middle "
            f"tier {middle}); {actions}; hold {c.hold_s:g} s"
        )

    def to_dict(self) -> dict:
        """Plain values for records: the thresholds and actions, the draw settings, the tier rule with its error."""
        return self.config.to_dict() | {"draws": dict(self.draws.__dict__), "tier": self.tier.settings()}


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
    """The Bayesian controller with the warning system: π(o) steers, the warning level of ``rule`` sets the speed.

    Draws as the rule's draw settings say (`uqdrive.policy.draws`; its cap: Chernoff's n for the config's θ, γ)
    and decides each frame's η2 tier by the rule's tier rule. A hand-over brakes with the steering wheel held
    where it was when it fired (the network is not trusted any more), at speed 0 with ``handover`` set; the
    rollout ends once the car has stopped. Each lockstep slot keeps its own actions' state.
    """

    def __init__(
        self, posterior: Posterior, bins: SteeringBins, rule: WarningRule, eps: float, speed: float, control_hz: float
    ):
        super().__init__(posterior, bins, rule.cap, eps, speed, rule.draws)
        self.rule, self.tier, self.tau = rule, rule.tier, rule.config.tau
        self.hold_frames = round(rule.config.hold_s * control_hz)
        self.actions = {0: WarningActions(rule.config.actions, self.hold_frames)}
        self.held_steer: dict[int, float | None] = {0: None}

    def reset(self, seed: int, slot: int = 0, world: Any = None) -> None:
        super().reset(seed, slot, world)
        self.actions[slot] = WarningActions(self.rule.config.actions, self.hold_frames)
        self.held_steer[slot] = None

    def commands(self, slots: Sequence[int], frames: Sequence[FrameDecision], infos: Sequence[dict]) -> list[Command]:
        """π(o) steers, the frame's warning level sets the speed (and may hand over)."""
        commands = super().commands(slots, frames, infos)
        levels = [int(levels_of(f.tier, f.mutual_information, self.rule.config.tau)) for f in frames]
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
