"""Is a candidate class the mode of the posterior predictive? A sequential test by betting, with a guarantee.

π(o) is the class of highest predictive probability q(c) = E_w[p_w(c | o)]. For a candidate c* (picked from
draws the test does not use), each further weight draw w_i gives the margin
T_i = p_i(c*) − max_{c ≠ c*} p_i(c) ∈ [−1, 1]. If c* is not the mode, some class c has q(c) > q(c*), so
E[T_i] ≤ q(c*) − q(c) < 0. The test bets on E[T] > 0: wealth K = Π (1 + λ_i T_i), each stake λ_i ∈ [0, λ_max]
fixed before T_i is seen (from the margins of earlier looks). When c* is not the mode, K is a non-negative
supermartingale starting at 1, so by Ville's inequality P(K ever reaches 1/γ) ≤ γ, at any number of looks and
whatever the posterior: **declaring c* the mode when K ≥ 1/γ is wrong with probability ≤ γ**, with no
indifference zone. The margins keep their magnitude (a test of the sign of each draw's vote, or of a class
drawn from each p_i, would turn a posterior whose every draw says 0.55 / 0.40 into coin flips), so frames
whose draws agree settle in a few draws. `tests/test_uq_mode.py` checks the error rate by simulation at
E[T] = 0, the hardest null, with its exact (Clopper–Pearson) upper bound below γ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

MAX_STAKE = 0.8
"""λ_max: a draw with T = −1 keeps 1 − λ_max of the wealth, so one disagreeing draw never ends the test."""


def margins(probs: np.ndarray, candidate: int) -> np.ndarray:
    """T_i = p_i(candidate) − max over the other classes of p_i, for draws ``probs`` [m, C]."""
    others = probs.copy()
    others[:, candidate] = -1.0
    return probs[:, candidate] - others.max(-1)


@dataclass
class ModeTest:
    """The betting test of one candidate at level ``gamma``; `update` each look's margins, in order."""

    gamma: float
    log_wealth: float = 0.0
    count: int = 0
    total: float = 0.0
    total_sq: float = 0.0
    stakes: list[float] = field(default_factory=list)

    def stake(self) -> float:
        """λ for the next look, from the margins seen so far (growth-optimal for a Gaussian guess of them:
        mean / second moment), within [0, λ_max]; 0 before any margin is seen."""
        if self.count == 0:
            return 0.0
        mean, second = self.total / self.count, self.total_sq / self.count
        return min(max(mean / second, 0.0), MAX_STAKE) if second > 0 else 0.0

    def observe(self, past: np.ndarray) -> None:
        """Margins seen before the test (the candidate's own draws): they set the first stake, not the wealth."""
        self.count += len(past)
        self.total += float(past.sum())
        self.total_sq += float(np.square(past).sum())

    def update(self, look: np.ndarray) -> bool:
        """Bet on one look's margins at the stake fixed before it; True once the wealth has reached 1/γ."""
        stake = self.stake()
        self.stakes.append(stake)
        if stake > 0:
            self.log_wealth += float(np.log1p(stake * np.asarray(look, dtype=np.float64)).sum())
        self.observe(look)
        return self.settled

    @property
    def settled(self) -> bool:
        return self.log_wealth >= math.log(1 / self.gamma)
