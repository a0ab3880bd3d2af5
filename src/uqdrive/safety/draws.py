"""How many posterior draws a controller's frame takes, and what the frame concludes from them.

``fixed`` is the paper's controller: n draws give π(o), the mutual information and the entropy, n more give η̂2
around that π(o) (Chernoff's n for the warning config's θ, γ: |η̂2 − η2| ≤ θ with probability ≥ 1 − γ).

``sequential`` draws what the frame's decisions need, in looks of ``look`` draws, at most n for π(o) and n for
η2 (n: the controller's ``samples``), almost every frame in one head call:

- π(o): a pilot look picks the candidate class (the mode of its draws' mean); further looks bet on its margin
  over the best other class (`uqdrive.uq.mode`): the candidate is declared the predictive mode with error ≤ γ,
  for any posterior. A frame that does not settle by the cap takes π(o) from all its n draws, as ``fixed``.
  The mutual information and entropy come from the same draws; a warning controller, whose warning 0 compares
  MI with τ, draws on (up to n; only in η2's top tier, the one warning 0 fires in) while τ lies within three
  jackknife standard errors of the MI, or within the MI a disagreement these draws cannot yet exclude would add
  (the rule of three: a share 3/m of the draws on another class adds about its binary entropy h(3/m); m draws
  that all agree have a jackknife error of 0). Approximate: no guarantee is claimed for MI, and none was at the
  paper's fixed n.
- η2 (a warning controller only): fresh draws, never those of π(o), so each is a Bernoulli draw of rate η2;
  sequential tests of η2 ≥ δ1 and η2 ≥ δ2 decide the tier with error ≤ γ when η2 is at least θ from both
  thresholds (`uqdrive.uq.tier`).

A controller that acts on no warning (``unacted``): its rollouts may be replayed by the threshold calibration
(`uqdrive.safety.calibration`: the avoid stage's warnings-off cells), which classifies each step's η̂2 and MI
against a grid of candidate thresholds, so it needs an η̂2 within θ of η2 whatever the thresholds and an MI as
precise as the fixed controller's, not a tier decided for one pair. ``record`` (the default) keeps the paper's
fixed draws for such a controller; ``skip``, for rollouts nobody replays (the offline-safety sweep never
calibrates), draws no η2 set and takes π(o) and MI from the mode test's draws.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from uqdrive.schema import Count, OpenUnit, schema
from uqdrive.uq import draw_measures, frame_measures, within_ball
from uqdrive.uq.mode import ModeTest, margins
from uqdrive.uq.tier import CONFIDENT, DOUBTFUL, UNSURE, TierTest


@schema(frozen=True)
class DrawSettings:
    """A frame's posterior draws: ``fixed`` (the paper's n + n) or ``sequential`` (as many as its decisions need,
    each decided with error ≤ ``gamma`` outside an indifference zone of ``theta``; ``look`` draws at a time).
    ``unacted``: what a controller that acts on no warning draws with ``sequential`` (module docstring): ``record``
    the fixed draws calibration replays, ``skip`` no η2 set."""

    scheme: Literal["fixed", "sequential"] = "fixed"
    theta: OpenUnit = 0.05
    gamma: OpenUnit = 0.05
    look: Count = 8
    unacted: Literal["record", "skip"] = "record"

    def fixed_for(self, acts_on_warnings: bool) -> bool:
        """Whether a controller that does (or does not) act on warnings takes the paper's fixed draws."""
        return self.scheme == "fixed" or (not acts_on_warnings and self.unacted == "record")


@dataclass(frozen=True)
class FrameDecision:
    """What one frame's draws give: π(o) (``decision``), η̂2 (NaN where no η2 set was drawn), the η2 ``tier`` for
    thresholds (δ1, δ2) (None where none were asked), mutual information with its standard error, entropy, the
    number of draws taken, and whether π(o) was ``settled`` by the mode test (sequential draws: declared the
    predictive mode with error ≤ γ) rather than estimated from every draw."""

    decision: float
    eta2: float
    tier: int | None
    mutual_information: float
    mutual_information_se: float
    entropy: float
    draws: int
    settled: bool = False


OutcomeStream = Callable[[int], np.ndarray]
"""``draw(m)``: m more posterior draws of one frame, class probabilities [m, C] from the frame's generator, in
numpy: the sequential path's few dozen draws per frame cost less in numpy than in torch."""


MI_Z = 3.0
"""Jackknife standard errors of the MI within which τ keeps a warning controller drawing."""


def unseen_mutual_information(draws: int) -> float:
    """The MI (nats) of a posterior whose share 3/m of draws (the rule of three's 95 % bound on what m agreeing
    draws have not shown) picks another class: the binary entropy of min(3/m, ½)."""
    share = min(3 / draws, 0.5)
    return -share * math.log(share) - (1 - share) * math.log1p(-share)


def mi_draws(tau: float, look: int, cap: int) -> int:
    """π(o)'s draws in a warning controller's first head call: the least multiple of ``look`` (≥ 2 looks) whose
    `unseen_mutual_information` is below τ, so that a frame whose draws agree decides warning 0 in that call."""
    m = 2 * look
    while m < cap and unseen_mutual_information(m) >= tau:
        m += look
    return min(m, cap)


def first_draws(cap: int, settings: DrawSettings, tier: TierTest | None = None, tau: float | None = None) -> int:
    """The draws of a frame's first head call under ``sequential``: the pilot, the first test look and η2's first
    looks (``tier``: None for no η2 set; ``tau``: the MI threshold a warning acts on, None if none). Every frame of
    a controller draws the same number first, so lockstep frames share that call."""
    pi = 2 * settings.look if tau is None else mi_draws(tau, settings.look, cap)
    return pi + (tier.first_draws if tier is not None else 0)


def sequential_frame(
    draw: OutcomeStream,
    first: np.ndarray,
    cap: int,
    centres: torch.Tensor,
    eps: float,
    settings: DrawSettings,
    tier: TierTest | None = None,
    tau: float | None = None,
) -> FrameDecision:
    """One frame with ``sequential`` draws (module docstring) from its first head call's draws ``first``
    [`first_draws`, C]; ``draw`` makes more. ``tier`` decides η2's tier (None: no η2 set), ``tau`` is the MI
    threshold a warning acts on (None: MI is only measured). Looks then double, so a frame whose draws disagree
    reaches the cap in a handful of calls."""
    look = settings.look
    first_pi = len(first) - (tier.first_draws if tier is not None else 0)
    pi_probs, choice, settled = _settle_mode(draw, first[:look], first[look:first_pi], cap, settings.gamma)
    decision = float(centres[choice])
    level, eta2, eta2_draws = None, math.nan, 0
    if tier is not None:
        outcomes = _Eta2Outcomes(draw, first[first_pi:], centres.numpy(), decision, eps)
        result = tier.run(outcomes)
        level, eta2, eta2_draws = result.tier, result.k / result.n, outcomes.drawn
    acts_on_mi = tau is not None and level in (None, CONFIDENT)  # warning 0 needs η2 ≥ δ1
    pi_probs, (mi, se, entropy) = _refine_mutual_information(draw, pi_probs, cap, tau if acts_on_mi else None)
    return FrameDecision(decision, eta2, level, mi, se, entropy, len(pi_probs) + eta2_draws, settled)


def _settle_mode(
    draw: OutcomeStream, pilot: np.ndarray, first: np.ndarray, cap: int, gamma: float
) -> tuple[np.ndarray, int, bool]:
    """Every draw made for π(o), its class and whether the test settled it: the pilot's mode once the betting test
    settles it, else the mode of all ``cap`` draws. The test's looks double; once the candidate's margins average
    ≤ 0 (it is not winning) the rest of the cap comes in one look."""
    candidate = int(pilot.mean(0).argmax())
    test = ModeTest(gamma)
    test.observe(margins(pilot, candidate))
    drawn, tested = [pilot, first], margins(first, candidate)
    settled, count, total = test.update(tested), len(pilot) + len(first), float(tested.sum())
    while not settled and count < cap:
        size = cap - count if total <= 0 else min(count - len(pilot), cap - count)
        drawn.append(draw(size))
        tested = margins(drawn[-1], candidate)
        settled, count, total = test.update(tested), count + size, total + float(tested.sum())
    probs = np.concatenate(drawn)
    return probs, candidate if settled else int(probs.mean(0).argmax()), settled


def _refine_mutual_information(
    draw: OutcomeStream, probs: np.ndarray, cap: int, tau: float | None
) -> tuple[np.ndarray, tuple[float, float, float]]:
    """π(o)'s draws and their (MI, MI's standard error, entropy); with ``tau``, after more draws (doubling, up to
    ``cap``) while τ lies within `MI_Z` jackknife standard errors of the MI or within the unseen MI of the draws
    (`unseen_mutual_information`)."""
    measures = draw_measures(probs)
    while tau is not None and len(probs) < cap and _undecided(measures, tau, len(probs)):
        probs = np.concatenate([probs, draw(min(len(probs), cap - len(probs)))])
        measures = draw_measures(probs)
    return probs, measures


def _undecided(measures: tuple[float, float, float], tau: float, draws: int) -> bool:
    mi, se, _ = measures
    return abs(mi - tau) < max(MI_Z * se, unseen_mutual_information(draws))


class _Eta2Outcomes:
    """η2's Bernoulli draws of one frame (is a fresh draw's decision within ε of π(o)?), served from the first
    head call's η2 draws, then drawn as the test asks for them."""

    def __init__(self, draw: OutcomeStream, first: np.ndarray, centres: np.ndarray, decision: float, eps: float):
        self.draw, self.centres, self.decision, self.eps = draw, centres, decision, eps
        self.pending, self.drawn = self.inside(first), len(first)

    def inside(self, probs: np.ndarray) -> np.ndarray:
        return within_ball(self.centres[probs.argmax(-1)], self.decision, self.eps)

    def __call__(self, count: int) -> np.ndarray:
        if len(self.pending) < count:
            more = self.draw(count - len(self.pending))
            self.pending, self.drawn = np.concatenate([self.pending, self.inside(more)]), self.drawn + len(more)
        served, self.pending = self.pending[:count], self.pending[count:]
        return served.astype(np.int64)


def eta2_tier(eta2: float, delta1: float, delta2: float) -> int:
    return DOUBTFUL if eta2 < delta2 else UNSURE if eta2 < delta1 else CONFIDENT


def fixed_frame(
    probs: torch.Tensor, centres: torch.Tensor, eps: float, thresholds: tuple[float, float] | None = None
) -> FrameDecision:
    """The paper's frame from its 2n draws ``probs`` [2n, C] (one head call): π(o), MI and entropy from the first n,
    η̂2 from the others."""
    n = len(probs) // 2
    m = frame_measures(probs.unsqueeze(1), centres, eps, split=n)
    eta2 = float(m.eta2[0])
    return FrameDecision(
        float(m.decision[0]),
        eta2,
        None if thresholds is None else eta2_tier(eta2, *thresholds),
        float(m.mutual_information[0]),
        float(m.mutual_information_se[0]),
        float(m.entropy[0]),
        2 * n,
    )
