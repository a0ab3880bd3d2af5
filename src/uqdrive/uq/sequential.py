"""Sequential estimation of a Bernoulli rate to ±θ with confidence 1 − γ, calibrated by exact computation.

Rule: look after every ``look_size`` samples; at a look with k successes in n samples, stop

* when the exact (Clopper–Pearson) interval at level 1 − ``level`` lies inside [k/n − θ, k/n + θ]
  (the *fit* rule), and report k/n; otherwise
* when a ball [c − θ, c + θ] has small edge tails, U = P(Bin(n, c + θ) ≤ k) and L = P(Bin(n, c − θ) ≥ k)
  (each 0 where its edge leaves [0, 1]): √(2(U² + L²)) ≤ ``ball_level`` (the *ball* rule), and
  report c. The balls tried are the end balls [0, 2θ] and [1 − 2θ, 1] and the one whose edges the
  count makes equally implausible, KL(k/n ‖ c − θ) = KL(k/n ‖ c + θ); the smallest level counts.

The reported interval is [max(0, c − θ), min(1, c + θ)] (c = k/n for the fit rule), its ends rounded
to 12 decimals, and it is the set whose coverage the calibration computes. The fit rule alone is the
scheme this one extends; it ends every run by the first look at which every count fits. Optional
stopping makes the level of the interval at the stop differ from the nominal one, so neither level
comes from a formula: ``level`` is the largest found whose fit rule alone has exact error
P(η ∉ interval) ≤ γ (:func:`calibrate_level`), then ``ball_level`` (≤ ``level``) the largest found
whose whole rule has (:func:`calibrate_ball_level`). The error is computed by dynamic programming over
the stopping rule (:mod:`uqdrive.uq.stopping`) at every η of a fine grid, both one-sided limits at
every jump and a local maximisation between jumps.

Why this scheme (exact, θ = γ = 0.05, a look every 4, `uqdrive bench estimators`): near 0 and 1 the
exact interval is lopsided — at k = 0 only its upper tail can fail — so k/n ± θ is the wrong ball to
test, and testing it costs 72 samples at η ∈ {0, 1}. The ball rule tests the ball the data settle
soonest: it expects 36 samples at η ∈ {0, 1} (the fit rule alone: 72), 44.1 at 0.01 or 0.99 (84.6),
93.0 at 0.05 or 0.95 (136.9), 174.0 at 0.1 or 0.9 (198.2), and where the fit rule decides, 400 at
η = ½ (fixed-n Clopper–Pearson: 404; Chernoff: 738), with exact worst error 0.0498. Wald's change of
measure bounds any (0.05, 0.05) estimator at about 33 expected samples at η = 0.99, and with looks of
4 at 32 at η ∈ {0, 1}. Alternatives measured while choosing (same exact computation, not kept as code):
reporting the centre of the Clopper–Pearson interval everywhere (no fit rule) costs the middle its
level, 439 at η = ½; combining the edge tails by their maximum (the Clopper–Pearson width) instead of
the root mean square gives 40 / 47.4 / 92.3 / 164.2 at η = 1 / 0.99 / 0.95 / 0.9, by their sum
36 / 44.2 / 97.3 / 186.5, and the exact minimiser of U² + L² in place of the balanced ball
36 / 44.1 / 92.9 / 172.4 at many times the cost.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np
from scipy import special

from uqdrive.uq.bounds import check_look_size, check_unit, fit_levels, fit_tails
from uqdrive.uq.stopping import StopPoints, Weight, stop_points

# (level, ball_level) calibrated offline by :func:`calibrate` (a test recomputes them), keyed by
# (θ, γ, look_size), so a sweep cell does not spend seconds calibrating.
CALIBRATED: dict[tuple[float, float, int], tuple[float, float]] = {
    (0.05, 0.05, 1): (0.05054446430258501, 0.03155493375985625),
    (0.05, 0.05, 4): (0.05142445360006273, 0.03295642729243186),
    (0.05, 0.05, 10): (0.05054446430258501, 0.042965482453061955),
    (0.1, 0.05, 1): (0.052213689121370685, 0.03187048309745483),
    (0.1, 0.05, 4): (0.050455574812958745, 0.03954379084316172),
    (0.1, 0.05, 10): (0.05571933712979463, 0.04706716272204419),
    (0.25, 0.05, 1): (0.06414350080393894, 0.0494614006596988),
    (0.25, 0.05, 4): (0.10787607977571198, 0.04946140065969876),
    (0.25, 0.05, 10): (0.11255306100218516, 0.11184673063608863),
    (0.05, 0.01, 1): (0.010100000000000003, 0.004991206802678315),
    (0.05, 0.01, 4): (0.01010889286051701, 0.005876810536826771),
    (0.05, 0.01, 10): (0.00989228013193976, 0.007265139979245269),
    (0.05, 0.05, 2): (0.05000000000000001, 0.032245896835166654),
    (0.05, 0.05, 8): (0.05100500000000001, 0.03807287934074799),
    (0.05, 0.05, 16): (0.05054446430258501, 0.04736439953967412),
    (0.05, 0.05, 20): (0.05278225891802785, 0.04715643187084853),
    (0.05, 0.05, 40): (0.05335702003384117, 0.04809779938089627),
}

GRID_POINTS = 2001
"""Regular η grid (spacing 1/2000) evaluated besides the one-sided limits at every jump."""

_GOLDEN = (math.sqrt(5) - 1) / 2  # golden-section search for the error's maxima between jumps
_DIGITS = 12  # reported ends are rounded: ends meant to coincide (0.545 − 0.05, 0.445 + 0.05) must not leave a gap
_SCAN = 1.01  # calibration's final scan: levels 1 %, 2 %, … 5 % above the bisection's
_CENTRE_STEPS = 24  # bisection steps for a ball's centre: bracket ≤ 2θ, so the centre to < 1e-7θ


def _edge_tails(n: np.ndarray, k: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P(Bin(n, high) ≤ k), P(Bin(n, low) ≥ k)), each 0 where its edge leaves (0, 1)."""
    with np.errstate(all="ignore"):
        upper = np.where(k >= n, 1.0, special.betainc(np.maximum(n - k, 1), k + 1, np.clip(1 - high, 0, 1)))
        lower = np.where(k <= 0, 1.0, special.betainc(np.maximum(k, 1), n - k + 1, np.clip(low, 0, 1)))
    return np.where(high >= 1, 0.0, upper), np.where(low <= 0, 0.0, lower)


def _best_balls(n: np.ndarray, k: np.ndarray, theta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For counts k (θ < ½): (level √(2(U² + L²)), centre, low, high) of the ball the count settles soonest.

    Candidates: the ball whose edges the count makes equally implausible, KL(k/n ‖ c − θ) =
    KL(k/n ‖ c + θ) (c in [θ, 1 − θ] within θ of k/n, by bisection: the difference falls with c),
    and the end balls [0, 2θ] and [1 − 2θ, 1], where one edge's tail is 0. The smallest level wins.
    Which ball is found only shapes the rule: its exact error is computed for the balls it reports.
    """
    p = k / n
    a, b = np.maximum(theta, p - theta), np.minimum(1 - theta, p + theta)
    with np.errstate(divide="ignore", invalid="ignore"):  # an empty bracket at θ or 1 − θ stays put
        for _ in range(_CENTRE_STEPS):
            c = (a + b) / 2
            # KL(p ‖ c − θ) − KL(p ‖ c + θ): > 0 while the lower edge is the less plausible one
            gap = p * np.log((c + theta) / (c - theta)) - (1 - p) * np.log((1 - c + theta) / (1 - c - theta))
            a, b = np.where(gap > 0, c, a), np.where(gap > 0, b, c)
    inner = (a + b) / 2
    centres = np.stack([inner, np.full(k.size, theta), np.full(k.size, 1 - theta)])
    lows = np.stack([np.maximum(0.0, inner - theta), np.zeros(k.size), np.full(k.size, 1 - 2 * theta)])
    highs = np.stack([np.minimum(1.0, inner + theta), np.full(k.size, 2 * theta), np.ones(k.size)])
    sizes = np.stack([np.add(*(t**2 for t in _edge_tails(n, k, lo, hi))) for lo, hi in zip(lows, highs)])
    best, pick = np.argmin(sizes, axis=0), np.arange(k.size)
    return np.sqrt(2 * sizes[best, pick]), centres[best, pick], lows[best, pick], highs[best, pick]


@lru_cache(maxsize=4096)
def _fit_table(n: int, theta: float) -> np.ndarray:
    """The fit rule at a look of n: rows (level at which k/n ± θ fits, k/n, low, high) over k = 0..n.
    Read-only (cached)."""
    value = np.arange(n + 1) / n
    low, high = np.maximum(0.0, value - theta), np.minimum(1.0, value + theta)
    table = np.stack([fit_levels(n, theta), value, np.round(low, _DIGITS), np.round(high, _DIGITS)])
    table.setflags(write=False)
    return table


@lru_cache(maxsize=8)
def _ball_tables(theta: float, looks: range, level: float, cap: float) -> dict[int, np.ndarray]:
    """The ball rule at every look n: rows (level, centre, low, high), columns the counts k = 0..n.

    Searched only where it can matter, all looks at once: not where the count fits at ``level`` (the
    fit rule stops there first), nor where the ball's level certainly exceeds ``cap`` — any ball has
    U ≥ U(k/n) if it lies lower than k/n ± θ and L ≥ L(k/n) if higher, so √2 · min(U(k/n), L(k/n))
    bounds it from below; there the level is +inf. For θ ≥ ½ the ball [0, 1] has level 0 everywhere.
    Read-only (cached).
    """
    if 2 * theta >= 1:
        return {n: np.tile(np.array([[0.0], [0.5], [0.0], [1.0]]), n + 1) for n in looks}
    todo = []
    for n in looks:
        upper, lower = fit_tails(n, theta)
        keep = (fit_levels(n, theta) > level) & (math.sqrt(2) * np.minimum(upper, lower) <= cap)
        todo.append(np.flatnonzero(keep))
    ns = np.concatenate([np.full(t.size, n) for n, t in zip(looks, todo)])
    level_found, centre, low, high = _best_balls(ns, np.concatenate(todo), theta)
    found = np.stack([level_found, centre, np.round(low, _DIGITS), np.round(high, _DIGITS)])
    tables, start = {}, 0
    for n, counts in zip(looks, todo):
        table = np.zeros((4, n + 1))
        table[0] = np.inf
        table[:, counts] = found[:, start : start + counts.size]
        table.setflags(write=False)
        tables[n], start = table, start + counts.size
    return tables


@dataclass(frozen=True)
class LookRule:
    """The rule at one look for some counts: stop?, and the reported value and interval."""

    stop: np.ndarray
    value: np.ndarray
    low: np.ndarray
    high: np.ndarray


@dataclass(frozen=True)
class SequentialScheme:
    """The stopping rule for (θ, γ, look_size) with the fit rule at ``level`` and the ball rule at
    ``ball_level`` (0: the fit rule alone)."""

    theta: float
    gamma: float
    look_size: int
    level: float
    ball_level: float = 0.0

    @cached_property
    def fit_end(self) -> int:
        """The first look at which every count's interval fits in ±θ: the fit rule alone stops every run there."""
        n = self.look_size
        while fit_levels(n, self.theta).max() > self.level:
            n += self.look_size
        return n

    def look(self, n: int, counts: np.ndarray) -> LookRule:
        """The rule after n samples (a multiple of ``look_size``) with each of ``counts`` successes."""
        fit = _fit_table(n, self.theta)[:, counts]
        stop, report = fit[0] <= self.level, fit[1:]
        if self.ball_level > 0:
            balls = self._balls[n][:, counts]
            ball = ~stop & (balls[0] <= self.ball_level)
            stop, report = stop | ball, np.where(ball, balls[1:], report)
        return LookRule(stop, *report)

    @cached_property
    def _balls(self) -> dict[int, np.ndarray]:
        return _ball_tables(self.theta, self.looks, self.level, max(self.level, self.ball_level))

    @property
    def looks(self) -> range:
        """Sample counts at which the rule looks: every ``look_size`` up to :attr:`fit_end`."""
        return range(self.look_size, self.fit_end + 1, self.look_size)

    @cached_property
    def stop_points(self) -> StopPoints:
        """The reachable stops, labelled with the interval (low, high) reported there."""

        def rule(n: int, counts: np.ndarray) -> tuple[np.ndarray, ...]:
            look = self.look(n, counts)
            return look.stop, look.low, look.high

        return stop_points(self.looks, rule)

    @cached_property
    def max_n(self) -> int:
        """The most samples any run takes."""
        return int(self.stop_points.n.max())

    @property
    def reported(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) reported at each stop point."""
        low, high = self.stop_points.labels
        return low, high

    def stops(self, k: int, n: int) -> bool:
        """Does the rule stop after n samples (a look) with k successes?"""
        return n >= self.max_n or bool(self.look(n, np.array([k])).stop[0])

    def report(self, k: int, n: int) -> tuple[float, float, float]:
        """(value, low, high) reported on stopping with k successes in n samples."""
        look = self.look(n, np.array([k]))
        return float(look.value[0]), float(look.low[0]), float(look.high[0])

    def _outside(self, side: int = 0) -> Weight:
        """Weight selecting the stop points whose interval misses η; ``side`` −1 / +1: as η ↑ / ↓ the given value."""
        low, high = self.reported
        if side < 0:
            return lambda i, eta: (eta <= low[i, None]) | (eta > high[i, None])
        if side > 0:
            return lambda i, eta: (eta < low[i, None]) | (eta >= high[i, None])
        return lambda i, eta: (eta < low[i, None]) | (eta > high[i, None])

    def operating_characteristics(self, rates: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Exact (expected samples, P(η outside the reported interval)) at each true rate (no one-sided limits)."""
        rates = np.atleast_1d(np.asarray(rates, dtype=float))
        return self.stop_points.expected_draws(rates), self.stop_points.mass(rates, self._outside())

    def worst_error(self, beyond: float = math.inf) -> float:
        """Largest exact error over η ∈ [0, 1]: both one-sided limits at every jump (an end of a reported
        interval), a fine grid, and a local maximisation inside the smooth piece around each of the
        largest grid values (between jumps the error is a smooth sum of binomial terms). Returns as soon
        as a value above ``beyond`` is found (that value, a lower bound on the worst error)."""
        low, high = self.reported
        jumps = np.unique(np.concatenate([low, high]))
        jumps = jumps[(jumps > 0) & (jumps < 1)]
        worst = float(self.stop_points.masses(jumps, [self._outside(-1), self._outside(1)]).max(initial=0))
        if worst > beyond:
            return worst
        grid = np.linspace(0, 1, GRID_POINTS)
        grid_error = self.stop_points.mass(grid, self._outside())
        worst = max(worst, float(grid_error.max()))
        if worst > beyond:
            return worst
        edges = np.unique(np.concatenate([[0.0, 1.0], jumps]))
        at = np.searchsorted(edges, grid[np.argsort(grid_error)[-8:]])
        pieces = np.unique(np.stack([edges[np.maximum(at - 1, 0)], edges[np.minimum(at, len(edges) - 1)]], 1), axis=0)
        return max(worst, _pieces_max(lambda eta: self.stop_points.mass(eta, self._outside()), pieces))


def _pieces_max(error: Callable[[np.ndarray], np.ndarray], pieces: np.ndarray) -> float:
    """Max of the (smooth) error over open pieces (lo, hi), all at once: the best of a fine sub-grid of
    each piece, then golden-section search around it."""
    lo, hi = pieces[:, :1], pieces[:, 1:]
    eta = lo + (hi - lo) * np.linspace(0, 1, 66)[None, 1:-1]
    values = error(eta.ravel()).reshape(eta.shape)
    i = values.argmax(1)
    rows = np.arange(len(pieces))
    a, b = eta[rows, np.maximum(i - 1, 0)], eta[rows, np.minimum(i + 1, eta.shape[1] - 1)]
    best = float(values.max())
    for _ in range(40):
        c, d = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
        ec, ed = np.split(error(np.concatenate([c, d])), 2)
        best = max(best, float(ec.max()), float(ed.max()))
        b, a = np.where(ec >= ed, d, b), np.where(ec >= ed, a, c)
    return best


def _largest_valid(make: Callable[[float], SequentialScheme], lo: float, hi: float, steps: int) -> float | None:
    """A level in [lo, hi] as large as can be found whose scheme has exact worst error ≤ γ; None if ``lo``'s has not.

    The error is not monotone in the level (at θ = γ = 0.05, a look every 4, the fit rule is valid at
    0.0493, not at 0.0495, valid again at 0.0517), so bisection on the log level (``steps`` halvings)
    finds a valid level and a scan then takes the largest valid one up to 5 % above it, in steps of
    1 % (tried from the top: most are rejected cheaply, at the first η found above γ). The returned
    level is one whose worst error was computed.
    """

    def valid(level: float) -> bool:
        scheme = make(level)
        return scheme.worst_error(beyond=scheme.gamma) <= scheme.gamma

    if not valid(lo):
        return None
    low, high = math.log(lo), math.log(hi)
    for _ in range(steps):
        mid = (low + high) / 2
        low, high = (mid, high) if valid(math.exp(mid)) else (low, mid)
    found = math.exp(low)
    above = [level for level in found * _SCAN ** np.arange(1, 6) if level <= hi]
    return next((level for level in reversed(above) if valid(level)), found)


def calibrate_level(theta: float, gamma: float, look_size: int) -> float:
    """The fit rule's level: as large as :func:`_largest_valid` finds in [γ/4, 4γ] with the fit rule alone's
    exact worst error ≤ γ."""
    theta, gamma, look_size = check_unit("theta", theta), check_unit("gamma", gamma), check_look_size(look_size)
    level = _largest_valid(
        lambda level: SequentialScheme(theta, gamma, look_size, level), gamma / 4, min(4 * gamma, 0.999), 8
    )
    if level is None:
        raise ValueError(f"no calibrated level found for theta={theta}, gamma={gamma}, look_size={look_size}")
    return level


def calibrate_ball_level(theta: float, gamma: float, look_size: int, level: float) -> float:
    """The ball rule's level beside the fit rule at ``level``: as large as :func:`_largest_valid` finds in
    [level/8, level] with exact worst error ≤ γ; 0.0 (the fit rule alone) if not even level/8 has."""
    theta, gamma, look_size = check_unit("theta", theta), check_unit("gamma", gamma), check_look_size(look_size)
    ball = _largest_valid(lambda ball: SequentialScheme(theta, gamma, look_size, level, ball), level / 8, level, 7)
    return 0.0 if ball is None else ball


def calibrate(theta: float, gamma: float, look_size: int) -> tuple[float, float]:
    """(level, ball_level) for (θ, γ, look_size): the fit rule's, then the ball rule's beside it."""
    level = calibrate_level(theta, gamma, look_size)
    return level, calibrate_ball_level(theta, gamma, look_size, level)


def sequential_scheme(theta: float, gamma: float, look_size: int = 1) -> SequentialScheme:
    """The calibrated scheme for (θ, γ, look_size): from the table, else calibrated once per process."""
    return _scheme(check_unit("theta", theta), check_unit("gamma", gamma), check_look_size(look_size))


@lru_cache(maxsize=64)
def _scheme(theta: float, gamma: float, look_size: int) -> SequentialScheme:
    levels = CALIBRATED.get((theta, gamma, look_size))
    if levels is None:
        levels = calibrate(theta, gamma, look_size)
    return SequentialScheme(theta, gamma, look_size, *levels)
