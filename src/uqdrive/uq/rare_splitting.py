"""Refute "η1 ≥ target" by multilevel splitting on the margin along a rollout, with the betting bound of
`uqdrive.uq.rare` — for worlds whose failure is decided by the time-course of a rollout, where sampling the start
condition cannot help (the suite's walk world: importance sampling on conditions 0.6× Monte Carlo).

One tree per condition drawn from the domain itself. A rollout's state is stepped (``world.advance``) and scored
(1 = failed; the score is the running progress toward failure, never decreasing, e.g. 1 − the margin so far).
Fixed splitting: when a particle's score first reaches level ℓ_k (fixed before the run) it is replaced by
``factor`` independent continuations from a copy of its state, each carrying weight factor^−k. The tree's
estimate X = Σ weights of its particles that failed. Unbiased: by induction over the levels, the expected weight
the copies of a particle at level k carry into failure is factor^−k · factor · factor^−1 · P(fail | its state) —
the copies continue the Markov process independently from the copied state (the state must hold everything the
future depends on: position, time, running maximum). So X ≥ 0, X ≤ 1 (the weights below a root sum to at most 1)
and E[X] = P(fail | condition); over a condition from the domain E[X] = p. Trees are independent and identically
distributed (no adaptation: the levels and factor are fixed), so the betting capital over trees
K_j = Π (1 + s_j (X_j − m)), s_j ∈ [0, c/m] predictable, is a nonnegative supermartingale under H0: p ≤ m, and
Ville's inequality gives P(refute at any tree) ≤ γ. The cost is counted in rollouts: steps simulated / horizon;
stopping when the spent cost reaches the budget is a stopping time of the trees' filtration.
Needs a world whose state can be copied (a simulator's save/restore); the synthetic walk world's can.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from uqdrive.uq.rare import BettingEvidence, RareSettings
from uqdrive.uq.rare_proposal import ProductBeta


class Stepped(Protocol):
    """A world whose rollouts can be stepped and their states copied (rows of an array)."""

    horizon: int

    def begin(self, points: np.ndarray) -> np.ndarray:
        """States [k, s] at step 0 of rollouts at conditions ``points`` [k, d]."""
        ...

    def advance(self, states: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One step of each: (states, score [k] (≥ 1: failed; never decreasing), done [k] (horizon reached))."""
        ...


@dataclass(frozen=True)
class Splitting:
    """Fixed splitting: ``levels`` of the score, increasing in (0, 1), and the ``factor`` each crossing splits by."""

    levels: tuple[float, ...]
    factor: int

    def __post_init__(self) -> None:
        levels = np.asarray(self.levels, float)
        if levels.size == 0 or not (np.all(np.diff(levels) > 0) and 0 < levels[0] and levels[-1] < 1):
            raise ValueError(f"splitting.levels={list(self.levels)} must increase strictly within (0, 1)")
        if self.factor < 2:
            raise ValueError(f"splitting.factor={self.factor} must be at least 2")


def tree_estimates(
    world: Stepped, points: np.ndarray, splitting: Splitting, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Per tree (one per condition, ``points`` [k, d]): (X, its unbiased estimate of P(fail | condition); cost
    in rollouts, steps simulated / horizon)."""
    trees = points.shape[0]
    levels = np.append(np.asarray(splitting.levels, float), np.inf)
    states, owner, stage = world.begin(points), np.arange(trees), np.zeros(trees, int)
    estimate, steps = np.zeros(trees), np.zeros(trees)
    while owner.size:
        steps += np.bincount(owner, minlength=trees)
        states, score, done = world.advance(states, rng)
        failed = score >= 1
        np.add.at(estimate, owner[failed], float(splitting.factor) ** -stage[failed])
        keep = ~failed & ~done
        states, owner, stage, score = states[keep], owner[keep], stage[keep], score[keep]
        copies = np.ones(owner.size, int)
        while True:
            crossed = score >= levels[stage]
            if not crossed.any():
                break
            stage, copies = stage + crossed, copies * np.where(crossed, splitting.factor, 1)
        states, owner, stage, score = (np.repeat(a, copies, axis=0) for a in (states, owner, stage, score))
    return estimate, steps / world.horizon


@dataclass(frozen=True)
class SplitRefutation:
    """Per run: ``refuted`` (η1 < target shown, error ≤ γ), ``rollouts`` spent (to the refutation, else the
    budget's), ``trees`` grown in them."""

    refuted: np.ndarray
    rollouts: np.ndarray
    trees: np.ndarray


def refute_by_splitting(
    world: Stepped,
    nominal: ProductBeta,
    settings: RareSettings,
    splitting: Splitting,
    rng: np.random.Generator,
    *,
    runs: int = 1,
) -> SplitRefutation:
    """Refute "η1 ≥ target" in ``runs`` independent runs, ``settings.round_size`` trees a round, each run stopping at
    its first rejection or when its cost reaches ``settings.refute_budget`` rollouts."""
    evidence = BettingEvidence(np.full(runs, settings.null), settings.gamma)
    n = settings.round_size
    stop, spent, trees = np.full(runs, -1.0), np.zeros(runs), np.zeros(runs, int)
    while ((stop < 0) & (spent < settings.refute_budget)).any():
        x, cost = tree_estimates(world, nominal.sample(rng, 1, runs * n)[0], splitting, rng)
        x, cost = x.reshape(runs, n), cost.reshape(runs, n)
        first = evidence.observe(x)
        before = spent[:, None] + np.cumsum(cost, 1) - cost  # cost spent before each tree
        live = (stop < 0)[:, None] & (before < settings.refute_budget)
        hit = live & (np.arange(n) == first[:, None])
        newly = hit.any(1)
        stop[newly] = (before + cost)[hit]
        counted = live & ((first[:, None] < 0) | (np.arange(n) <= first[:, None]))
        trees += counted.sum(1)
        spent += (cost * counted).sum(1)
    refuted = stop >= 0
    return SplitRefutation(refuted, np.where(refuted, stop, spent), trees)
