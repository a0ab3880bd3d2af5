"""How many posterior draws a controller's frame takes, and what the frame concludes from them.

``fixed`` is the paper's controller: n draws give π(o), the mutual information and the entropy, n more give η̂2
around that π(o) (Chernoff's n for the warning config's θ, γ: |η̂2 − η2| ≤ θ with probability ≥ 1 − γ); the η2
tier is that of η̂2 (`uqdrive.uq.tier.FixedTier`).

``sequential`` draws what the frame's decisions need, in looks of ``look`` draws, at most n for π(o) and n for
η2 (n: the controller's ``samples``), almost every frame in one head call:

- π(o): a pilot look picks the candidate class (the mode of its draws' mean); further looks bet on its margin
  over the best other class (`uqdrive.uq.mode`): the candidate is declared the predictive mode with error ≤ γ,
  for any posterior. A frame that does not settle by the cap takes π(o) from all its n draws, as ``fixed``.
  The mutual information and entropy come from the same draws; a warning controller, whose warning 0 compares
  MI with τ, draws on (doubling, up to n; only in η2's top tier, the one warning 0 fires in) while τ lies within
  three jackknife standard errors of the MI, or within the MI a disagreement these draws cannot yet exclude would
  add (the rule of three: a share 3/m of the draws on another class adds about its binary entropy h(3/m); m
  draws that all agree have a jackknife error of 0). Approximate: no guarantee is claimed for MI, and none was
  at the paper's fixed n.
- η2: fresh draws, never those of π(o), so each is a Bernoulli draw of rate η2.

Each frame's π(o) draws and η2 draws come from two streams of the frame's own (`frame_generator`: seeded by the
episode's seed, the frame's index and the stream), each drawn in chunks fixed in advance (a posterior's m draws
and then m' more need not be its m + m' draws at once): η2's at its looks, doubling from the first head call's
24 (`DrawSettings.looks`), π(o)'s as the mode test and then MI's doublings ask. So a frame's draws are the same
however far it reads them, and how far it reads changes no other draw. A warning controller reads η2's stream
until its tier rule decides (`uqdrive.uq.tier.TierTest`: error ≤ γ outside ±θ of both thresholds, computed
exactly) and π(o)'s until its MI is decided for its τ. A controller that acts on no warning (``unacted``) reads
both to the cap (``record``, the default) and records the successes at every look of η2's stream and the MI at
every stage of π(o)'s: what the threshold calibration needs to replay any thresholds' rule exactly as its
controller would have read the same streams (`uqdrive.avoid.trace_replay`). ``skip``, for rollouts nobody replays
(the offline-safety sweep never calibrates), draws no η2 stream and no MI stage past π(o)'s.

Warnings off and on so differ only by the warnings: on the same seed they draw the same streams, take the same
π(o), and their rollouts are identical frame by frame until a warning action first changes a command.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np
import torch

from uqdrive.schema import Count, OpenUnit, schema
from uqdrive.uq import draw_measures, frame_measures, within_ball
from uqdrive.uq.mode import ModeTest, margins
from uqdrive.uq.threshold import doubling_looks
from uqdrive.uq.tier import FixedTier, TierRule, TierTest


@schema(frozen=True)
class DrawSettings:
    """A frame's posterior draws: ``fixed`` (the paper's n + n) or ``sequential`` (as many as its decisions need,
    each decided with error ≤ ``gamma`` outside an indifference zone of ``theta``; ``look`` draws at a time).
    ``unacted``: what a controller that acts on no warning draws with ``sequential`` (module docstring):
    ``record`` both streams to the cap, which calibration replays, ``skip`` no η2 and no MI stage."""

    scheme: Literal["fixed", "sequential"] = "fixed"
    theta: OpenUnit = 0.05
    gamma: OpenUnit = 0.05
    look: Count = 8
    unacted: Literal["record", "skip"] = "record"

    @property
    def method(self) -> DrawScheme:
        """The scheme ``scheme`` names, as an object (`DRAW_SCHEMES`)."""
        return DRAW_SCHEMES[self.scheme]

    def looks(self, cap: int) -> tuple[int, ...]:
        """Draw counts at which a frame's η2 draws are read (and their successes recorded): doubling from the
        first head call's (`first_draws`) to ``cap`` (sequential), or ``cap`` alone (fixed). They are also where
        π(o)'s draws stop for MI when the mode settles in the first call, so a recorded frame draws both streams'
        chunks in the same head calls."""
        return self.method.looks(self, cap)

    def records(self, acts_on_warnings: bool) -> bool:
        """Whether a controller reads its frames' streams to the cap whatever it decides (to record them)."""
        return self.method.records(self, acts_on_warnings)


class FrameDecider(Protocol):
    """What decides a batch of frames from their features, by either scheme (`uqdrive.policy.controller`)."""

    def decide_fixed(self, features: torch.Tensor, episodes: list) -> list[FrameDecision]: ...

    def decide_sequential(self, features: torch.Tensor, episodes: list) -> list[FrameDecision]: ...


class DrawScheme(Protocol):
    """How a frame's posterior draws are taken and read (module docstring): the looks its η2 stream is read at,
    whether a controller records both streams to the cap, the tier rule its warnings use and the accuracy that
    rule is held to (with the config keys that set it), and which of a controller's decisions runs."""

    name: str
    tier_kind: type[TierRule]

    def looks(self, settings: DrawSettings, cap: int) -> tuple[int, ...]: ...

    def records(self, settings: DrawSettings, acts_on_warnings: bool) -> bool: ...

    def tier_accuracy(self, settings: DrawSettings, theta: float, gamma: float) -> tuple[float, float, str]:
        """(θ, γ) of the tier rule, given the warning config's, and the keys that set them."""

    def decide(self, decider: FrameDecider, features: torch.Tensor, episodes: list) -> list[FrameDecision]: ...


@dataclass(frozen=True)
class FixedDraws:
    """The paper's n + n draws, read at once; its tier rule is held to the warning config's (θ, γ)."""

    name: str = "fixed"
    tier_kind: type[TierRule] = FixedTier

    def looks(self, settings: DrawSettings, cap: int) -> tuple[int, ...]:
        return (int(cap),)

    def records(self, settings: DrawSettings, acts_on_warnings: bool) -> bool:
        return True

    def tier_accuracy(self, settings: DrawSettings, theta: float, gamma: float) -> tuple[float, float, str]:
        return theta, gamma, "warning.theta, warning.gamma"

    def decide(self, decider: FrameDecider, features: torch.Tensor, episodes: list) -> list[FrameDecision]:
        return decider.decide_fixed(features, episodes)


@dataclass(frozen=True)
class SequentialDraws:
    """As many draws as each decision needs, in doubling looks; its tier rule is held to the draws' (θ, γ)."""

    name: str = "sequential"
    tier_kind: type[TierRule] = TierTest

    def looks(self, settings: DrawSettings, cap: int) -> tuple[int, ...]:
        return doubling_looks(first_draws(settings, cap), cap)

    def records(self, settings: DrawSettings, acts_on_warnings: bool) -> bool:
        return not acts_on_warnings and settings.unacted == "record"

    def tier_accuracy(self, settings: DrawSettings, theta: float, gamma: float) -> tuple[float, float, str]:
        return settings.theta, settings.gamma, "draws.theta, draws.gamma and draws.look"

    def decide(self, decider: FrameDecider, features: torch.Tensor, episodes: list) -> list[FrameDecision]:
        return decider.decide_sequential(features, episodes)


DRAW_SCHEMES: dict[str, DrawScheme] = {s.name: s for s in (FixedDraws(), SequentialDraws())}


@dataclass(frozen=True)
class FrameDecision:
    """What one frame's draws give: π(o) (``decision``), η̂2 (successes over the η2 draws read; NaN where none
    were), the η2 ``tier`` of a warning controller's rule (None where none was asked), mutual information with its
    standard error, entropy, the number of draws taken, whether π(o) was ``settled`` by the mode test (sequential
    draws: declared the predictive mode with error ≤ γ) rather than estimated from every draw, and
    ``eta2_counts``: the successes at each look of the η2 stream read (all looks when recorded); ``mi_stages``:
    (draws, MI, SE) at each stage of π(o)'s draws read (every doubling to the cap when recorded)."""

    decision: float
    eta2: float
    tier: int | None
    mutual_information: float
    mutual_information_se: float
    entropy: float
    draws: int
    settled: bool = False
    eta2_counts: tuple[int, ...] = ()
    mi_stages: tuple[tuple[int, float, float], ...] = ()


Draws = Callable[[int], np.ndarray]
"""``draw(m)``: m more posterior draws of one frame, class probabilities [m, C] from one of the frame's
generators, in numpy: the sequential path's few dozen draws per frame cost less in numpy than in torch."""

PI_STREAM, ETA2_STREAM = 0, 1
MI_Z = 3.0
"""Jackknife standard errors of the MI within which τ keeps a warning controller drawing."""


def frame_generator(seed: int, frame: int, stream: int) -> torch.Generator:
    """The generator of ``stream`` (`PI_STREAM`, `ETA2_STREAM`) in frame ``frame`` (0, 1, …) of the episode with
    ``seed``: however many draws a frame reads, every other draw of the episode is the same."""
    state = np.random.SeedSequence((int(seed), int(frame), int(stream))).generate_state(1, np.uint64)[0]
    return torch.Generator().manual_seed(int(state))


def first_draws(settings: DrawSettings, cap: int) -> int:
    """Draws of each stream in a frame's first head call: a pilot look and a first tested look of two for π(o)
    (24 at look 8: h(3/24) = 0.38 nats, so a frame whose draws agree decides τ = 0.45 in that call), as many of
    η2's (its first look: all 24 agreeing settle the tier at δ1 = 0.7), so both streams share the call."""
    return min(3 * settings.look, cap)


def unseen_mutual_information(draws: np.ndarray | int) -> np.ndarray:
    """The MI (nats) of a posterior whose share 3/m of draws (the rule of three's 95 % bound on what m agreeing
    draws have not shown) picks another class: the binary entropy of min(3/m, ½)."""
    share = np.minimum(3 / np.asarray(draws, float), 0.5)
    return -share * np.log(share) - (1 - share) * np.log1p(-share)


def mi_decided(
    mi: np.ndarray | float, se: np.ndarray | float, draws: np.ndarray | int, tau: np.ndarray | float
) -> np.ndarray:
    """Whether a warning controller with MI threshold τ stops drawing for MI: τ lies at least `MI_Z` jackknife
    standard errors and the unseen MI of the draws away from the MI (NaN stages never decide)."""
    return np.abs(np.asarray(mi) - tau) >= np.maximum(MI_Z * np.asarray(se), unseen_mutual_information(draws))


def refined_mutual_information(stages: np.ndarray, tau: np.ndarray | float) -> np.ndarray:
    """The MI a warning controller with threshold τ ends with, from recorded stages [..., S, 3] (draws, MI, SE at
    each doubling of π(o)'s draws; NaN past the last): the first stage that decides τ, else the last (the cap)."""
    draws, mi, se = np.moveaxis(np.asarray(stages, float), -1, 0)
    valid = ~np.isnan(draws)
    with np.errstate(invalid="ignore"):
        stop = valid & mi_decided(mi, se, np.where(valid, draws, 1), tau)
    at = np.where(stop.any(-1), stop.argmax(-1), np.maximum(valid.sum(-1) - 1, 0))
    return np.take_along_axis(mi, at[..., None], -1)[..., 0]


class Eta2Stream:
    """One frame's η2 outcomes (is a fresh draw's decision within ε of π(o)?), drawn look by look (``looks``: the
    first in the frame's first head call), served in order as a tier rule asks for them (`TierRule.run`)."""

    def __init__(
        self,
        draw: Draws,
        looks: tuple[int, ...],
        first: np.ndarray,
        centres: np.ndarray,
        decision: float,
        eps: float,
    ):
        self.draw, self.looks = draw, looks
        self.centres, self.decision, self.eps = centres, decision, eps
        self.outcomes = np.zeros(0, np.int64)
        self.served = 0
        self.extend(first)

    def extend(self, probs: np.ndarray) -> None:
        """Add the outcomes of the stream's next chunk of draws [m, C]."""
        inside = within_ball(self.centres[probs.argmax(-1)], self.decision, self.eps)
        self.outcomes = np.concatenate([self.outcomes, inside.astype(np.int64)])

    def next_chunk(self) -> int:
        """Draws to the stream's next look (0 at the cap)."""
        return next((n for n in self.looks if n > len(self.outcomes)), len(self.outcomes)) - len(self.outcomes)

    def __call__(self, count: int) -> np.ndarray:
        while len(self.outcomes) < self.served + count:
            self.extend(self.draw(self.next_chunk()))
        self.served += count
        return self.outcomes[self.served - count : self.served]

    def counts(self) -> tuple[int, ...]:
        """Successes among the first n outcomes at each look n served."""
        total = np.concatenate([[0], np.cumsum(self.outcomes)])
        return tuple(int(total[n]) for n in self.looks if n <= self.served)


def settle_mode(draw: Draws, first: np.ndarray, cap: int, settings: DrawSettings) -> tuple[np.ndarray, int, bool]:
    """Every draw made for π(o), its class and whether the test settled it, from the frame's first π(o) draws
    ``first`` (a pilot look, then the first tested look) and ``draw`` for more: the pilot's mode once the betting
    test settles it, else the mode of all ``cap`` draws. The test's looks double; once the candidate's margins
    average ≤ 0 (it is not winning) the rest of the cap comes in one look."""
    pilot = first[: settings.look]
    candidate = int(pilot.mean(0).argmax())
    test = ModeTest(settings.gamma)
    test.observe(margins(pilot, candidate))
    drawn, tested = [first], margins(first[settings.look :], candidate)
    settled, count, total = test.update(tested), len(first), float(tested.sum())
    while not settled and count < cap:
        size = cap - count if total <= 0 else min(count - len(pilot), cap - count)
        drawn.append(draw(size))
        tested = margins(drawn[-1], candidate)
        settled, count, total = test.update(tested), count + size, total + float(tested.sum())
    probs = np.concatenate(drawn)
    return probs, candidate if settled else int(probs.mean(0).argmax()), settled


def mutual_information_stages(
    draw: Draws, probs: np.ndarray, cap: int, tau: float | None
) -> tuple[int, tuple[tuple[int, float, float], ...], float]:
    """π(o)'s draws after MI's own, doubling up to ``cap`` while τ is not decided (`mi_decided`; ``tau`` None:
    none; a recorded frame doubles to the cap in the same steps). Returns the draws made, each stage's (draws,
    MI, SE) and the entropy at the last stage."""
    mi, se, entropy = draw_measures(probs)
    stages = [(len(probs), mi, se)]
    while len(probs) < cap and tau is not None and not mi_decided(mi, se, len(probs), tau):
        probs = np.concatenate([probs, draw(min(len(probs), cap - len(probs)))])
        mi, se, entropy = draw_measures(probs)
        stages.append((len(probs), mi, se))
    return len(probs), tuple(stages), entropy


def sequential_frame(
    decision: float,
    settled: bool,
    stages: tuple[int, tuple[tuple[int, float, float], ...], float],
    stream: Eta2Stream | None,
    level: int | None,
) -> FrameDecision:
    """One frame with ``sequential`` draws, from π(o) (`settle_mode`), its MI stages (`mutual_information_stages`)
    and η2's stream (read by the tier rule that decided ``level``, or whole, or None: not drawn)."""
    pi_draws, mi_stages, entropy = stages
    _, mi, se = mi_stages[-1]
    served = stream.served if stream is not None else 0
    eta2 = int(stream.outcomes[:served].sum()) / served if served else float("nan")
    counts, drawn = (stream.counts(), len(stream.outcomes)) if stream is not None else ((), 0)
    return FrameDecision(decision, eta2, level, mi, se, entropy, pi_draws + drawn, settled, counts, mi_stages)


def fixed_frame(probs: torch.Tensor, centres: torch.Tensor, eps: float, tier: TierRule | None = None) -> FrameDecision:
    """The paper's frame from its 2n draws ``probs`` [2n, C] (one head call): π(o), MI and entropy from the first n,
    η̂2 = k/n from the others (k: those within ε of π(o)), the tier by ``tier`` (`FixedTier`) from k."""
    n = len(probs) // 2
    m = frame_measures(probs[:n].unsqueeze(1), centres, eps)
    decision = float(m.decision[0])
    k = int(within_ball(centres[probs[n:].argmax(-1)], decision, eps).sum())
    mi, se = float(m.mutual_information[0]), float(m.mutual_information_se[0])
    return FrameDecision(
        decision,
        k / n,
        None if tier is None else tier.decide(k, n),
        mi,
        se,
        float(m.entropy[0]),
        2 * n,
        eta2_counts=(k,),
        mi_stages=((n, mi, se),),
    )
