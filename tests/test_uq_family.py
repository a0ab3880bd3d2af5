"""Controller-level findings over replicates: the average gain over these controllers and its betting interval.

Coverage by simulation, 10,000 repetitions a design: n = 14 and 29 runs, R = 2 and 10 controllers, alike and
unlike (one controller gaining what the others lose, skewed, all discordant pairs on one side); each end's miss
rate's 95 % Clopper–Pearson upper limit below level/2. Exactly, by enumerating every sequence, for 10 runs of one
controller and 5 runs of two (worst one-sided miss 0.006 at level 0.05). The interval the findings printed before
(π's interval drawn at the observed discordance) fails the same check. Supported ⇔ the interval excludes 0 ⇔
p ≤ level on random comparisons; more replicates give more power."""

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq.family import Comparison, decide_finding, decide_findings
from uqdrive.uq.paired import share_interval
from uqdrive.uq.verdict import Reason, Verdict

REPS = 10_000


def upper(count: int, reps: int = REPS) -> float:
    """Top of the 95 % Clopper–Pearson interval of a simulated rate."""
    return float(stats.beta.ppf(0.975, count + 1, reps - count)) if count < reps else 1.0


def outcomes(rng, reps: int, n: int, controllers: list[tuple[float, float]]) -> np.ndarray:
    """Paired differences X ∈ {−1, 0, 1} shaped [reps, n, R]: controller r's pairs have P(only A safe) = p_a,
    P(only B safe) = p_b."""
    u = rng.random((reps, n, len(controllers)))
    p_a, p_b = (np.array(v) for v in zip(*controllers))
    return np.where(u < p_a, 1.0, np.where(u < p_a + p_b, -1.0, 0.0))


def comparison(x: np.ndarray) -> Comparison:
    """One simulated comparison from differences shaped [n, R] (A safe where X = 1, B where X = −1)."""
    return Comparison("a vs b", {r: (x[:, r] >= 0, x[:, r] <= 0) for r in range(x.shape[1])})


def interval(x: np.ndarray, level: float):
    """The findings' interval on many simulated comparisons at once (the same function `decide_finding` calls)."""
    from uqdrive.uq.betting import mean_interval

    reps, n, controllers = x.shape
    return mean_interval(x.reshape(reps, n * controllers), -1.0, 1.0, level, block=controllers)


DESIGNS = {
    "alike, no gain": lambda r: [(0.2, 0.2)] * r,
    "alike, all discordant pairs for A": lambda r: [(0.3, 0.0)] * r,
    "unlike: half gain, half lose": lambda r: [(0.6, 0.0)] * (r // 2) + [(0.0, 0.6)] * (r - r // 2),
    "unlike: one gains what the others lose": lambda r: [(0.9, 0.0)] + [(0.0, 0.9 / (r - 1))] * (r - 1),
    "skewed: rare wins, frequent small losses": lambda r: [(0.02, 0.0)] * (r - 1) + [(0.0, 0.02 * (r - 1))],
}


@pytest.mark.parametrize("n", [14, 29])
@pytest.mark.parametrize("replicates", [2, 10])
@pytest.mark.parametrize("design", list(DESIGNS))
def test_the_interval_covers_the_average_gain(n, replicates, design):
    level = 0.05
    controllers = DESIGNS[design](replicates)
    truth = float(np.mean([a - b for a, b in controllers]))
    rng = np.random.default_rng([n, replicates, len(design)])
    result = interval(outcomes(rng, REPS, n, controllers), level)
    misses = int(np.sum(result.low > truth + 1e-12)), int(np.sum(result.high < truth - 1e-12))
    assert max(upper(m) for m in misses) < level / 2, (misses, truth)


def test_the_interval_covers_at_a_stricter_level():
    """10 unlike controllers at 29 runs, level 0.01: each end's miss rate's upper limit below 0.005."""
    controllers = DESIGNS["unlike: one gains what the others lose"](10)
    truth = float(np.mean([a - b for a, b in controllers]))
    result = interval(outcomes(np.random.default_rng(7), REPS, 29, controllers), 0.01)
    misses = int(np.sum(result.low > truth + 1e-12)), int(np.sum(result.high < truth - 1e-12))
    assert max(upper(m) for m in misses) < 0.005, misses


def old_interval(x: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """The interval the findings printed before: π's exact interval on the pooled discordant pairs at the
    level, drawn at the observed discordance d̂ — a picture of π's interval, not an interval for Δ."""
    ends = []
    for sample in x.reshape(x.shape[0], -1):
        a, b = int(np.sum(sample > 0)), int(np.sum(sample < 0))
        low, high = share_interval(a, a + b, level)
        ends.append(((a + b) / sample.size * (2 * low - 1), (a + b) / sample.size * (2 * high - 1)))
    return tuple(np.array(e) for e in zip(*ends))


@pytest.mark.parametrize("n", [14, 29])
def test_the_old_interval_fails_the_same_check(n):
    """All discordant pairs favour A: the old interval ends at the point estimate and misses Δ about half the
    time (the new one, on the same samples, within its level)."""
    x = outcomes(np.random.default_rng(n), 2_000, n, [(0.3, 0.0)] * 2)
    low, high = old_interval(x, 0.05)
    assert np.mean((low > 0.3) | (high < 0.3)) > 0.3
    new = interval(x, 0.05)
    assert np.mean((new.low > 0.3) | (new.high < 0.3)) < 0.05


def test_supported_is_exactly_an_interval_without_zero_and_p_below_the_level():
    rng = np.random.default_rng(3)
    for _ in range(300):
        n, replicates = int(rng.integers(3, 30)), int(rng.integers(1, 5))
        p_a, p_b = rng.dirichlet([1, 1, 1])[:2] if rng.random() < 0.7 else (rng.random() * 0.9, 0.0)
        x = outcomes(rng, 1, n, [(p_a, p_b)] * replicates)[0]
        for level in (0.3, 0.05, 0.001):
            finding = decide_finding(comparison(x), level, 0.05)
            assert finding.supported == (finding.low > 0 or finding.high < 0) == (finding.p_value <= level)
            assert finding.low <= finding.effect <= finding.high
            assert finding.verdict is (Verdict.SUPPORTED if finding.supported else Verdict.UNDECIDED)


def test_a_family_splits_alpha_and_reads_each_controllers_table():
    strong = np.array([1.0] * 20 + [0.0] * 20)
    x = np.stack([strong, strong], -1)
    nothing = np.stack([np.array([1.0, -1.0] * 4 + [0.0] * 32)] * 2, -1)
    first, second = decide_findings([comparison(x), comparison(nothing)], 0.05)
    assert first.level == pytest.approx(0.025) and first.supported and first.low > 0 and first.runs == 40
    assert first.effect == pytest.approx(0.5) and first.replicates == (0, 1)
    assert first.a_only == {0: 20, 1: 20} and first.b_only == {0: 0, 1: 0}  # each controller's table of 40 runs
    assert not second.supported and second.reason is Reason.NOT_SIGNIFICANT and second.low <= 0 <= second.high
    unlike = np.stack([np.array([1.0] * 24 + [0.0] * 16), np.array([-1.0] * 24 + [0.0] * 16)], -1)
    assert not decide_findings([comparison(unlike)], 0.05)[0].supported  # one gains what the other loses
    with pytest.raises(ValueError, match="at least one comparison"):
        decide_findings([Comparison("empty", {})], alpha=0.05)


def test_more_replicates_give_more_power():
    """A gain of 0.2 in every controller at 29 runs, at the level one comparison of the quick run's family (126
    comparisons) gets: the share supported rises with the number of controllers."""
    level, rng = 0.05 / 126, np.random.default_rng(11)
    powers = []
    for replicates in (2, 4, 10):
        result = interval(outcomes(rng, 2_000, 29, [(0.25, 0.05)] * replicates), level)
        powers.append(float(np.mean(result.low > 0)))
    assert powers == sorted(powers) and powers[-1] > 0.9 and powers[0] < 0.5, powers


@pytest.mark.parametrize("runs, replicates", [(10, 1), (5, 2)])
def test_the_interval_covers_exactly_on_every_sequence_of_a_small_design(runs, replicates):
    """Every sequence of paired differences enumerated (3^10 of them) with its probability, the interval computed
    on each once: each end's miss probability at most level/2 on a grid of (P(only A), P(only B)), the controllers
    alike or each at its own grid point."""
    level = 0.05
    sequences = (
        np.array(np.meshgrid(*[[-1.0, 0.0, 1.0]] * (runs * replicates), indexing="ij")).reshape(runs * replicates, -1).T
    )
    result = interval(sequences.reshape(-1, runs, replicates), level)
    wins, losses = (sequences == 1.0), (sequences == -1.0)
    controller = np.arange(runs * replicates) % replicates
    steps = np.linspace(0, 1, 11)
    points = [(a, b) for a in steps for b in steps if a + b <= 1 + 1e-12]
    rng, worst = np.random.default_rng(runs), 0.0
    for _ in range(300):
        chosen = [points[i] for i in rng.integers(len(points), size=replicates)]
        p_a, p_b = (np.array(v)[controller] for v in zip(*chosen))
        law = np.prod(np.where(wins, p_a, np.where(losses, p_b, np.clip(1 - p_a - p_b, 0, 1))), axis=1)
        truth = float(np.mean([a - b for a, b in chosen]))
        worst = max(worst, law @ (result.low > truth + 1e-12), law @ (result.high < truth - 1e-12))
    assert worst <= level / 2, worst
