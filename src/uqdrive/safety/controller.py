"""Closed-loop controllers: camera frame (or state) → steering and speed, one control period at a time.

`Controller` is the paper's Bayesian end-to-end controller: the frame goes through the same
preprocessing the training data went through, then n posterior draws give π(o), η2 and the
mutual information. `AutopilotPolicy` and `ConstantPolicy` use the same interface so the safe
sets can be checked against controllers whose safety is known (η1 ≈ 1 and ≈ 0).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import to_inputs
from uqdrive.data.frames import preprocess_frame
from uqdrive.models.posterior import Posterior
from uqdrive.safety.draws import DrawSettings, FrameDecision, first_draws, fixed_frame, sequential_frame
from uqdrive.sim import Autopilot, AutopilotConfig, DrivingEnv
from uqdrive.uq.tier import TierTest

NO_WARNING = -1
"""Warning level of a frame that raised none (levels 0, 1, 2: see `uqdrive.safety.warnings`)."""


@dataclass(frozen=True)
class Command:
    """One control decision; the uncertainty fields are NaN for controllers without a posterior.

    ``warning``, ``alert``, ``handover``: set by a controller with the warning system; with
    ``handover`` the car brakes to a stop and the rollout ends there (control goes to the operator).
    """

    steer: float
    speed: float
    eta2: float = math.nan
    mutual_information: float = math.nan
    entropy: float = math.nan
    warning: int = NO_WARNING
    alert: bool = False
    handover: bool = False
    draws: int = 0  # posterior draws the frame took
    mutual_information_se: float = math.nan  # jackknife standard error of the MI at those draws


class Policy(Protocol):
    """What rollouts drive with, one or several in lockstep: each rollout has a ``slot``, and `act_batch` decides
    the current frame of every slot in ``slots`` at once. ``needs_camera``: False lets the rollout skip rendering."""

    needs_camera: bool

    def reset(self, env: DrivingEnv, seed: int, slot: int = 0) -> None:
        """Start the episode in ``slot`` (env already reset); every random draw of the episode comes from ``seed``."""

    def act_batch(
        self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]
    ) -> list[Command]:
        """Commands for the current frame and state of each of ``slots``."""


class Controller:
    """Bayesian end-to-end controller: steer = π(o), the class centre of the predictive's mode.

    Each frame draws 2·``n_samples`` weight samples: the first n give π(o), the mutual
    information and the entropy, the other n give η2 around that π(o). With π(o) picked from
    the draws that also count η2, η̂2 would not be a plain binomial mean (π(o) is chosen where
    the draws agree), and Chernoff's n (or any estimator in `uqdrive.uq`) would not apply as
    stated. Separate draws make η̂2 a binomial mean given π(o), exactly; the alternative, a
    union bound over the 21 class centres, needs ln(2·21/γ)/(2θ²) = 1347 draws (1.8×) at
    θ = γ = 0.05, nearly the same cost, and grows with the class count. Cost: one batched
    head evaluation of 2n instead of n (`uqdrive bench controller`, budget 10 ms per frame).

    Rollouts in lockstep share one trunk pass and one first head call per step (`Posterior.features_each`,
    `Posterior.head_probs_each`: each frame's numbers those of the frame alone), each slot drawing from its own
    generator, seeded by its episode's seed, so a rollout's commands do not depend on the rollouts beside it.
    """

    needs_camera = True

    thresholds: tuple[float, float] | None = None
    """(δ1, δ2) whose η2 tier a frame decides: a controller that acts on no warning asks none."""
    tau: float | None = None
    """The MI threshold a warning acts on (sequential draws refine MI near it); None: MI is only measured."""

    def __init__(
        self,
        posterior: Posterior,
        bins: SteeringBins,
        n_samples: int,
        eps: float,
        speed: float,
        draws: DrawSettings | None = None,
    ):
        self.posterior = posterior.eval()
        self.centres = torch.as_tensor(bins.centres, dtype=torch.float32)
        self.n_samples, self.eps, self.speed = n_samples, float(eps), float(speed)
        self.draws = draws or DrawSettings()
        self.generators = {0: torch.Generator()}
        self.tier: TierTest | None = None  # sequential draws: the η2 tier test of a controller that acts on one

    def reset(self, env: DrivingEnv, seed: int, slot: int = 0) -> None:
        self.generators.setdefault(slot, torch.Generator()).manual_seed(seed)

    def act(self, obs: np.ndarray | None, info: dict | None = None) -> Command:
        """The command for one frame, in slot 0."""
        return self.act_batch([0], [obs], [info or {}])[0]

    @torch.inference_mode()  # no autograd bookkeeping on the frame's ~100 small tensor ops
    def act_batch(
        self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]
    ) -> list[Command]:
        if any(frame is None for frame in frames):
            raise ValueError("Controller needs a camera frame; reset the env with render=True")
        x = to_inputs(
            np.stack([preprocess_frame(frame) for frame in frames])
        )  # exactly what the network was trained on
        features = self.posterior.features_each(x)
        return self.commands(slots, self.decide(features, [self.generators[slot] for slot in slots]), infos)

    def decide(self, features: torch.Tensor, generators: Sequence[torch.Generator]) -> list[FrameDecision]:
        """Each frame's decisions from its features (a row of [K, F]) and draws from its slot's generator: the
        first draws of every frame in one head call (`Posterior.head_probs_each`), more for a frame that needs them
        from that frame alone, and every step each frame's own (a reduction over a batch of frames could round
        differently), so a frame's decisions are those it takes alone."""
        fixed = self.draws.fixed_for(acts_on_warnings=self.thresholds is not None)
        first = 2 * self.n_samples if fixed else first_draws(self.n_samples, self.draws, self.tier, self.tau)
        probs = self.posterior.head_probs_each(features, first, generators)
        if fixed:
            return [fixed_frame(p, self.centres, self.eps, self.thresholds) for p in probs]
        return [
            sequential_frame(
                self._more_draws(features[k : k + 1], generator),
                p.numpy(),
                self.n_samples,
                self.centres,
                self.eps,
                self.draws,
                self.tier,
                self.tau,
            )
            for k, (p, generator) in enumerate(zip(probs, generators))
        ]

    def _more_draws(self, features: torch.Tensor, generator: torch.Generator):
        """``draw(m)``: m more draws [m, C] of the frame whose features are ``features`` [1, F]."""
        return lambda m: self.posterior.head_probs_each(features, m, [generator])[0].numpy()

    def commands(self, slots: Sequence[int], frames: Sequence[FrameDecision], infos: Sequence[dict]) -> list[Command]:
        """Steer at π(o), at the cruise speed."""
        return [
            Command(
                f.decision,
                self.speed,
                f.eta2,
                f.mutual_information,
                f.entropy,
                draws=f.draws,
                mutual_information_se=f.mutual_information_se,
            )
            for f in frames
        ]


class AutopilotPolicy:
    """The pure-pursuit autopilot that produced the training data (unperturbed: a reference of η1 ≈ 1)."""

    needs_camera = False

    def __init__(self, config: AutopilotConfig | None = None):
        self.config = config or AutopilotConfig()
        self._autopilots: dict[int, Autopilot] = {}

    def reset(self, env: DrivingEnv, seed: int, slot: int = 0) -> None:
        self._autopilots[slot] = Autopilot(env.route, env.vehicle_config, self.config, env.control_hz, seed=seed)

    def act_batch(
        self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]
    ) -> list[Command]:
        actions = [self._autopilots[slot].act(info) for slot, info in zip(slots, infos)]
        return [Command(action.steer, action.speed) for action in actions]


class ConstantPolicy:
    """Fixed steering and speed (full left = +1: a reference of η1 ≈ 0)."""

    needs_camera = False

    def __init__(self, steer: float, speed: float):
        self.steer, self.speed = float(steer), float(speed)

    def reset(self, env: DrivingEnv, seed: int, slot: int = 0) -> None:
        """Nothing random to seed."""

    def act_batch(
        self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]
    ) -> list[Command]:
        return [Command(self.steer, self.speed) for _ in slots]
