"""Exact operating characteristics of a stopping rule on a sequence of Bernoulli draws.

A rule looks at cumulative draw counts ``looks[0] < looks[1] < …``; at a look with k successes
in n draws it either stops or draws on, and it must stop every run at its last look. Whether a
run stops at (n, k) depends only on its path, and every ordering of k successes in n draws has
the same probability η^k (1 − η)^(n−k), so P(stop at (n, k) | η) = w · C(n, k) η^k (1 − η)^(n−k),
where w, the fraction of those orderings that reach (n, k) without stopping earlier, does not
depend on η: one pass of dynamic programming (:func:`stop_points`) serves every η. Everything
a rule's guarantee needs — error probabilities, expected draws — is a sum over its stop points.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from scipy import special

StopRule = Callable[[int, np.ndarray], tuple[np.ndarray, ...]]
"""``rule(n, counts) -> (stop, *labels)``: does a run stop at this look (n draws) with each of these success
counts, and what it reports there (arrays over the counts, kept at the stops as :attr:`StopPoints.labels`)."""

Weight = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``weight(stop point indices [m], rates [1, r])`` -> [m, r] weights (booleans select)."""

_CHUNK = 64  # rates evaluated at once, neighbours in η: each chunk skips the stop points far from it


class StopPoints(NamedTuple):
    """Every reachable stop (n, k) with ``log_mass`` = log(w · C(n, k)), so that
    P(stop at (n, k) | η) = exp(log_mass) η^k (1 − η)^(n−k); ``labels``: what the rule reports there."""

    n: np.ndarray
    k: np.ndarray
    log_mass: np.ndarray
    labels: tuple[np.ndarray, ...] = ()

    def _blocks(self, rates: np.ndarray):
        """Yield (rate indices, indices of the stop points near them, P[near, rates]) over chunks of rates.

        Terms below e^−50 are left out: w ≤ 1 and P(Bin(n, η) = k) ≤ exp(−2n(k/n − η)²), so a stop
        point farther than 5/√n from η is skipped (the dropped mass is < 1e-18 per rate).
        """
        eta = np.asarray(rates, dtype=float)
        with np.errstate(divide="ignore"):  # log 0 = −inf stands for "no mass unless the exponent is 0"
            log_eta = np.where(eta > 0, np.log(eta), -1e300)
            log_rest = np.where(eta < 1, np.log1p(-eta), -1e300)
        rate, reach = self.k / self.n, 5 / np.sqrt(self.n)
        order = np.argsort(eta)
        for i in range(0, eta.size, _CHUNK):
            part = order[i : i + _CHUNK]
            near = np.flatnonzero((rate + reach >= eta[part[0]]) & (rate - reach <= eta[part[-1]]))
            k, rest = self.k[near, None], (self.n - self.k)[near, None]
            yield part, near, np.exp(self.log_mass[near, None] + k * log_eta[None, part] + rest * log_rest[None, part])

    def probabilities(self, rates: np.ndarray) -> np.ndarray:
        """[stop point, rate] matrix of P(the run stops there | η = rate)."""
        out = np.zeros((self.n.size, np.size(rates)))
        for part, near, prob in self._blocks(rates):
            out[np.ix_(near, part)] = prob
        return out

    def masses(self, rates: np.ndarray, weights: Sequence[Weight]) -> np.ndarray:
        """[weight, rate]: Σ over stop points of P(stop there | η) · weight(stop points, η), in one pass."""
        eta = np.asarray(rates, dtype=float)
        out = np.zeros((len(weights), eta.size))
        for part, near, prob in self._blocks(eta):
            for row, weight in zip(out, weights):
                row[part] = (prob * weight(near, eta[None, part])).sum(0)
        return out

    def mass(self, rates: np.ndarray, weight: Weight) -> np.ndarray:
        """Σ over stop points of P(stop there | η) · weight(stop points, η), for each rate."""
        return self.masses(rates, [weight])[0]

    def expected_draws(self, rates: np.ndarray) -> np.ndarray:
        """E[n] at each rate."""
        return self.mass(rates, lambda near, _: self.n[near, None])


def _log_choose(n: np.ndarray | int, k: np.ndarray) -> np.ndarray:
    return special.gammaln(n + 1) - special.gammaln(k + 1) - special.gammaln(n - k + 1)


_CACHED_MOVES = 100_000  # entries of a move table kept in the many-table cache
_LARGE_MOVES = 4_000_000  # … and in the eight-table cache (≤ 256 MB); larger ones are rebuilt each time


def _moves(n: int, m: int, low: int, size: int) -> np.ndarray:
    """[j, i]: of the orderings of K = low + i + j successes in n + m draws, the fraction whose last m draws
    hold j successes — the hypergeometric C(m, j) C(n, low + i) / C(n + m, K). Only the band a run can be in
    (i < size) is built: [m + 1, size], not [m + 1, n + m + 1], which at a cap of 10⁵ draws looked at 3·10⁴
    and on would hold 10⁹ entries. Read-only (cached where small)."""
    if (m + 1) * size <= _CACHED_MOVES:
        return _cached_moves(n, m, low, size)
    if (m + 1) * size <= _LARGE_MOVES:  # a calibration meets the same large tables at each of its ~30 passes
        return _large_moves(n, m, low, size)
    return _move_table(n, m, low, size)


@lru_cache(maxsize=4096)
def _cached_moves(n: int, m: int, low: int, size: int) -> np.ndarray:
    return _move_table(n, m, low, size)


@lru_cache(maxsize=8)
def _large_moves(n: int, m: int, low: int, size: int) -> np.ndarray:
    return _move_table(n, m, low, size)


def _move_table(n: int, m: int, low: int, size: int) -> np.ndarray:
    j = np.arange(m + 1)[:, None]
    before = low + np.arange(size)[None, :]  # counts in 0 … n: the band lies inside
    moves = np.exp(_log_choose(m, j) + _log_choose(n, before) - _log_choose(n + m, before + j))
    moves.setflags(write=False)
    return moves


def _advance(alive: np.ndarray, low: int, n: int, m: int) -> np.ndarray:
    """Fractions still running at counts low … low + size − 1 + m after m more draws (n → n + m):
    a run at count K after them came from count K − j, j the successes among the m new draws."""
    moves = _moves(n, m, low, alive.size)
    out = np.zeros(alive.size + m)
    if alive.size <= m:  # loop over the shorter side: the band (rare events, long looks) or the draws
        for i in range(alive.size):
            out[i : i + m + 1] += alive[i] * moves[:, i]
    else:
        for j in range(m + 1):
            out[j : j + alive.size] += alive * moves[j]
    return out


def stop_points(looks: Sequence[int], rule: StopRule) -> StopPoints:
    """The stop points of ``rule`` over ``looks`` (increasing draw counts), by dynamic programming.

    ``rule`` is asked only about the counts some run can have at a look (a contiguous band).
    Raises ``ValueError`` if a run is still running after the last look.
    """
    ns, ks, logs, labels = [], [], [], []
    alive = np.ones(1)  # fraction of the orderings of k successes still running, k = low … low + size − 1
    low, drawn = 0, 0
    for n in looks:
        n = int(n)
        alive, drawn = _advance(alive, low, drawn, n - drawn), n
        counts = low + np.arange(alive.size)
        stop, *label = rule(n, counts)
        stop = np.asarray(stop, dtype=bool) & (alive > 0)
        ns.append(n)
        ks.append(counts[stop])
        logs.append(np.log(alive[stop]))
        labels.append([np.asarray(values)[stop] for values in label])
        alive = np.where(stop, 0.0, alive)
        running = np.flatnonzero(alive > 0)
        if running.size == 0:
            k = np.concatenate(ks)
            n_at = np.repeat(ns, [len(stops) for stops in ks])
            kept = tuple(np.concatenate(values) for values in zip(*labels))
            return StopPoints(n_at, k, np.concatenate(logs) + _log_choose(n_at, k), kept)
        low, alive = low + int(running[0]), alive[running[0] : running[-1] + 1]
    raise ValueError(f"the rule leaves runs going after its last look ({int(looks[-1])} draws)")
