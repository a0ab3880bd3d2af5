"""The sequential threshold test: exact error, computed here independently of `uqdrive.uq`.

The rule is read through the public `decide(k, n)` at every look and count; P(above), P(below) and
E[n] are then computed by a forward dynamic program over the count distribution at each η of a fine
grid (the error probabilities are polynomials in η, continuous, so the grid and the edges δ ± θ
themselves give the suprema over the open sets), and for a small cap by enumerating every sequence
of outcomes.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from uqdrive.uq import ThresholdDecision, ThresholdTest, chernoff_n, doubling_looks
from uqdrive.uq.threshold import _boundaries, _tails

CAP = chernoff_n(0.05, 0.05)  # 738: the fixed-n controller's draws per frame
EVERY_4 = (*range(4, CAP, 4), CAP)


def decisions(test: ThresholdTest) -> dict[int, np.ndarray]:
    """look n → decision code per count k = 0..n (+1 above, −1 below, 0 none), through `decide`."""
    code = {"above": 1, "below": -1, None: 0}
    return {n: np.array([code[test.decide(k, n)] for k in range(n + 1)]) for n in test.looks}


def forward(rule: dict[int, np.ndarray], etas: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P(above), P(below), E[n]) at each η: the count distribution of the runs still going, draw by draw.

    ``dist[j]`` is P(still running with k = low + j successes); only the band of running counts is kept.
    """
    dist, low = np.ones((1, etas.size)), 0
    above, below, mean_n = np.zeros(etas.size), np.zeros(etas.size), np.zeros(etas.size)
    last = max(rule)
    for n in range(1, last + 1):
        nxt = np.zeros((dist.shape[0] + 1, etas.size))
        nxt[:-1] += dist * (1 - etas)
        nxt[1:] += dist * etas
        dist = nxt
        if n in rule:
            code = rule[n][low : low + dist.shape[0]]
            above += dist[code == 1].sum(0)
            below += dist[code == -1].sum(0)
            stop = (code != 0) | (n == last)
            mean_n += n * dist[stop].sum(0)
            running = np.flatnonzero(~stop)
            if running.size == 0:
                break
            dist, low = dist[running[0] : running[-1] + 1] * ~stop[running[0] : running[-1] + 1, None], low + running[0]
    return above, below, mean_n


GRID = np.linspace(0, 1, 1001)


def assert_guarantee(test: ThresholdTest, rule: dict[int, np.ndarray]) -> tuple[float, float]:
    """P(above | η ≤ δ − θ) ≤ γ and P(below | η ≥ δ + θ) ≤ γ over the grid and at the edges; the worst of each."""
    low, high = test.low_edge, test.high_edge
    etas = np.concatenate([GRID[(GRID <= low) | (GRID >= high)], [low, high]])
    above, below, _ = forward(rule, etas)
    worst_above = float(above[etas <= low].max())
    worst_below = float(below[etas >= high].max())
    assert worst_above <= test.gamma and worst_below <= test.gamma
    return worst_above, worst_below


@pytest.mark.parametrize("looks", [EVERY_4, doubling_looks(8, CAP)], ids=["every4", "doubling8"])
@pytest.mark.parametrize("delta", [0.6, 0.7])
def test_forced_controller_errs_at_most_gamma_outside_the_indifference_zone(delta: float, looks: tuple) -> None:
    test = ThresholdTest(delta, 0.05, looks, theta=0.05, forced=True)
    rule = decisions(test)
    worst = assert_guarantee(test, rule)
    assert max(worst) >= 0.8 * test.gamma  # the calibration spends the budget, not a fraction of it
    np.testing.assert_allclose(worst, test.worst_errors(), rtol=1e-9)
    k = np.arange(CAP + 1)
    undecided_by_tails = rule[CAP] == 0
    assert not undecided_by_tails.any()  # forced: every count decides at the cap …
    estimate = np.where(k / CAP >= delta, 1, -1)
    tails = _boundaries(test, _tails(test), test.above_level, test.below_level)
    by_estimate = (k < tails.above_from[-1]) & (k > tails.below_to[-1])
    np.testing.assert_array_equal(rule[CAP][by_estimate], estimate[by_estimate])  # … by k/n ≥ δ where no tail did


def test_expected_draws_of_the_controller_at_delta_07() -> None:
    """δ = 0.7, θ = γ = 0.05, a look every 4 up to 738: 12 draws when every draw agrees (0.65^12 ≤ level)."""
    test = ThresholdTest(0.7, 0.05, EVERY_4, theta=0.05, forced=True)
    etas = np.array([0.0, 0.5, 0.7, 0.9, 0.99, 1.0])
    above, below, mean_n = forward(decisions(test), etas)
    own_above, own_below, own_n = test.operating_characteristics(etas)
    np.testing.assert_allclose(own_n, mean_n, rtol=1e-9)
    np.testing.assert_allclose(np.stack([own_above, own_below]), np.stack([above, below]), atol=1e-12)
    assert mean_n[-1] == pytest.approx(12) and mean_n[0] == pytest.approx(4)
    assert mean_n[-2] <= 14 and mean_n[-3] <= 26 and mean_n[2] <= 200  # vs 738 for the fixed-n controller
    assert above[-1] == 1 and below[0] == 1


@pytest.mark.parametrize(("threshold", "gamma", "theta"), [(0.9, 0.05 / 20, 0.0), (0.5, 0.01, 0.0), (0.8, 0.05, 0.05)])
def test_certifier_errs_at_most_gamma(threshold: float, gamma: float, theta: float) -> None:
    """Unforced: P(certify above | η < τ) ≤ γ, P(certify below | η ≥ τ) ≤ γ for every η (θ = 0), undecided allowed."""
    test = ThresholdTest(threshold, gamma, tuple(range(20, 401, 20)), theta=theta, forced=False)
    rule = decisions(test)
    worst = assert_guarantee(test, rule)
    assert max(worst) >= 0.8 * gamma
    if theta == 0:
        assert (rule[400] == 0).any()  # some counts stay undecided at the budget
        above, below, _ = forward(rule, np.array([threshold]))
        assert above[0] + below[0] <= 2 * gamma  # at τ itself it mostly stays undecided


def test_enumeration_of_every_sequence_matches_the_operating_characteristics() -> None:
    """A small cap: every one of the 2^12 outcome sequences run through `run`; decisions summed exactly."""
    test = ThresholdTest(0.5, 0.1, (2, 4, 6, 8, 10, 12), theta=0.25, forced=True)
    etas = np.array([0.1, 0.3, 0.5, 0.7, 0.9])
    above, below, mean_n = np.zeros(etas.size), np.zeros(etas.size), np.zeros(etas.size)
    for outcomes in itertools.product((0, 1), repeat=12):
        x = np.array(outcomes)
        used = iter(np.split(x, [2, 4, 6, 8, 10]))
        result = test.run(lambda m: next(used))  # noqa: B023
        prob = etas ** x.sum() * (1 - etas) ** (12 - x.sum())  # the whole sequence; the run reads a prefix
        above += prob * (result.decision == "above")
        below += prob * (result.decision == "below")
        mean_n += prob * result.n
    own_above, own_below, own_n = test.operating_characteristics(etas)
    np.testing.assert_allclose(own_above, above, atol=1e-12)
    np.testing.assert_allclose(own_below, below, atol=1e-12)
    np.testing.assert_allclose(own_n, mean_n, rtol=1e-12)


def test_run_follows_decide_look_by_look() -> None:
    test = ThresholdTest(0.7, 0.05, EVERY_4, theta=0.05)
    rng = np.random.default_rng(7)
    for rate in (0.2, 0.68, 0.95):
        batches: list[np.ndarray] = []

        def draw(m: int, batches: list[np.ndarray] = batches, rate: float = rate) -> np.ndarray:
            batches.append((rng.random(m) < rate).astype(int))
            return batches[-1]

        result = test.run(draw)
        counts = np.cumsum(np.concatenate(batches))
        assert isinstance(result, ThresholdDecision) and result.n == counts.size and result.k == counts[-1]
        assert [test.decide(int(counts[n - 1]), n) for n in test.looks if n < result.n] == [None] * (result.n // 4 - 1)
        assert result.decision == test.decide(result.k, result.n) is not None
    undecided = ThresholdTest(0.7, 0.05, (10, 20), theta=0.0, forced=False).run(lambda m: np.arange(m) % 10 < 7)
    assert undecided == ThresholdDecision(None, 20, 14)


def test_a_doubled_level_is_seen_to_overshoot() -> None:
    """The check can fail: the same test with its "above" level doubled errs more than γ at δ − θ."""
    test = ThresholdTest(0.7, 0.05, EVERY_4, theta=0.05)
    doubled = _boundaries(test, _tails(test), 2 * test.above_level, test.below_level)
    rule = {
        n: np.where(np.arange(n + 1) >= a, 1, np.where(np.arange(n + 1) <= b, -1, 0))
        for n, a, b in zip(test.looks, doubled.above_from, doubled.below_to)
    }
    above, _, _ = forward(rule, np.array([test.low_edge]))
    assert above[0] > 0.05


def test_built_once_per_parameter_set() -> None:
    first = ThresholdTest(0.6, 0.05, EVERY_4, theta=0.05)
    again = ThresholdTest(0.6, 0.05, list(EVERY_4), theta=0.05)
    assert again == first and again._bounds is first._bounds


def test_edges_outside_the_unit_interval_leave_that_side_unguarded() -> None:
    test = ThresholdTest(0.98, 0.05, EVERY_4, theta=0.05)
    assert test.high_edge == 1.0 and test.decide(3, 4) == "below"  # one contrary draw: no η ≥ 1.03 to protect
    assert_guarantee(test, decisions(test))


def test_doubling_looks() -> None:
    assert doubling_looks(8, 738) == (8, 16, 32, 64, 128, 256, 512, 738)
    assert doubling_looks(8, 64) == (8, 16, 32, 64)
    with pytest.raises(ValueError, match=r"first must be an integer in \[1, cap=10\], got 0"):
        doubling_looks(0, 10)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"theta": 0.0, "forced": True}, r"a forced test needs theta > 0"),
        ({"looks": (8, 8, 16)}, r"looks must be increasing integer draw counts >= 1, got \(8, 8, 16\)"),
        ({"looks": (0, 8)}, r"looks must be increasing integer draw counts >= 1"),
        ({"looks": (4.5, 8)}, r"looks must be increasing integer draw counts >= 1"),
        ({"theta": -0.1}, r"theta must be in \[0, 1\), got -0.1"),
        ({"threshold": 1.0}, r"threshold must be in \(0, 1\), got 1.0"),
        ({"gamma": 0.0}, r"gamma must be in \(0, 1\), got 0.0"),
        ({"looks": (4, 8, 12)}, r"no test with error <= gamma=0.05 .* within 12 draws: the cap is too small"),
    ],
)
def test_bad_parameters_are_rejected(kwargs: dict, message: str) -> None:
    args = {"threshold": 0.7, "gamma": 0.05, "looks": EVERY_4, "theta": 0.05, "forced": True, **kwargs}
    with pytest.raises(ValueError, match=message):
        ThresholdTest(**args)


def test_decide_rejects_a_count_off_the_schedule() -> None:
    test = ThresholdTest(0.7, 0.05, EVERY_4, theta=0.05)
    with pytest.raises(ValueError, match=r"decide needs n in looks"):
        test.decide(3, 5)
    with pytest.raises(ValueError, match=r"decide needs n in looks"):
        test.decide(9, 8)
