"""Picklable recipes of uqdrive's own policies, each built once in every worker (`PolicyRecipe`); a user's policy's
recipe is `uqdrive.policy.policy_files.UserPolicySpec`."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Protocol

from uqdrive.data.binning import SteeringBins
from uqdrive.models.checkpoint import load_posterior
from uqdrive.policy.controller import Controller
from uqdrive.policy.draws import DrawSettings
from uqdrive.policy.interface import Policy
from uqdrive.policy.references import ConstantPolicy, ExpertPolicy
from uqdrive.policy.warnings import WarningController, WarningRule
from uqdrive.sim import AutopilotConfig


class PolicyRecipe(Protocol):
    """What a job drives with: a picklable recipe each worker builds its `Policy` from, once (`ControllerSpec`,
    `ExpertSpec`, `ConstantSpec`: uqdrive's; `UserPolicySpec`: a user's). The engine asks nothing else of it: no
    policy's kind."""

    def build(self, control_hz: float) -> Policy:
        """The policy (the engine drives it in lockstep: `uqdrive.policy.slots.in_lockstep`)."""


@dataclasses.dataclass(frozen=True)
class ControllerSpec:
    """A picklable recipe for uqdrive's Bayesian controller (`Controller`), built once in each worker: the posterior
    from ``model_path``; ``warnings``: with the warning system (`WarningController`), deployed by this `WarningRule`
    (its cap must be ``samples`` and its draw settings ``draws``: warnings on and off differ only by the warnings).
    ``draws``: how many posterior draws a frame takes (`DrawSettings`: the paper's fixed ``samples`` + ``samples``,
    or sequential with ``samples`` as the cap)."""

    speed: float
    model_path: str
    method: str
    bins: SteeringBins = dataclasses.field(default_factory=SteeringBins)
    samples: int = 1
    eps: float = 0.1
    warnings: WarningRule | None = None
    draws: DrawSettings = dataclasses.field(default_factory=DrawSettings)

    def __post_init__(self) -> None:
        w = self.warnings
        if w is not None and (self.samples != w.cap or w.draws != self.draws):
            raise ValueError(
                f"a controller with warnings must have samples={w.cap} (chernoff_n of warning.theta, warning.gamma) "
                f"and the rule's draws {w.draws}, got samples={self.samples}, draws {self.draws}"
            )

    def build(self, control_hz: float) -> Policy:
        posterior = load_posterior(Path(self.model_path), expected_method=self.method, expected_classes=self.bins)
        if self.warnings is not None:
            return WarningController(posterior, self.bins, self.warnings, self.eps, self.speed, control_hz)
        return Controller(posterior, self.bins, self.samples, self.eps, self.speed, self.draws)


@dataclasses.dataclass(frozen=True)
class ExpertSpec:
    """The world's expert (`ExpertPolicy`: the unperturbed autopilot that produced the training data, a reference
    of η1 ≈ 1; an acquisition's expert line)."""

    autopilot: AutopilotConfig = dataclasses.field(default_factory=AutopilotConfig)

    def build(self, control_hz: float) -> Policy:
        return ExpertPolicy(self.autopilot)


@dataclasses.dataclass(frozen=True)
class ConstantSpec:
    """Fixed steering and speed (full left, steer = +1: a reference of η1 ≈ 0)."""

    steer: float
    speed: float

    def build(self, control_hz: float) -> Policy:
        return ConstantPolicy(self.steer, self.speed)
