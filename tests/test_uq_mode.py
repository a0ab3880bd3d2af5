"""The betting test that a candidate class is the predictive mode: its error rate at the hardest null (the
candidate's margin has mean 0) is below γ by simulation, the rate's exact upper confidence bound included, at
γ = 0.05 and at γ = 0.5 (where the bound is nearest); frames whose draws agree settle within a look or two."""

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq.mode import MAX_STAKE, ModeTest, margins

CAP, LOOK, GAMMA = 738, 8, 0.05


def settles(draws: np.ndarray, gamma: float = GAMMA) -> bool:
    """One test over ``draws`` [CAP] of margins, a pilot look first (it sets the first stake only)."""
    test = ModeTest(gamma)
    test.observe(draws[:LOOK])
    return any(test.update(draws[i : i + LOOK]) for i in range(LOOK, CAP, LOOK))


NULLS = {  # margins with mean exactly 0: the candidate ties the best other class (the hardest case for the test)
    "coin, ±1": lambda rng, size: rng.choice([-1.0, 1.0], size),
    "small, ±0.1": lambda rng, size: rng.choice([-0.1, 0.1], size),
    "rare big wins": lambda rng, size: np.where(rng.random(size) < 0.1, 0.9, -0.1),
    "uniform": lambda rng, size: rng.uniform(-0.5, 0.5, size),
}


@pytest.mark.parametrize("null", NULLS)
def test_declaring_a_tied_candidate_the_mode_is_rarer_than_gamma(null):
    rng = np.random.default_rng(7)
    reps = 800
    wrong = sum(settles(NULLS[null](rng, CAP)) for _ in range(reps))
    upper = stats.beta.ppf(0.975, wrong + 1, reps - wrong)  # the top of the rate's 95 % Clopper-Pearson interval
    assert upper < GAMMA, (null, wrong)


@pytest.mark.parametrize("null", NULLS)
def test_at_a_loose_level_a_tied_candidate_is_still_declared_at_most_gamma_of_the_time(null):
    """γ = 0.5, where the error comes nearest its bound (about 0.2 here, against 0.01–0.02 of 0.05 above): the
    wealth must still double before a tie is declared the mode. A test settling at wealth 1/(2γ) declares it at
    any look whose wealth has not fallen (0.77–0.86 of the time); at γ = 0.05 its error (0.02–0.05) can pass."""
    rng, gamma, reps = np.random.default_rng(8), 0.5, 400
    wrong = sum(settles(NULLS[null](rng, CAP), gamma) for _ in range(reps))
    assert stats.beta.ppf(0.975, wrong + 1, reps - wrong) < gamma, (null, wrong)


def test_agreeing_draws_settle_at_the_first_look_and_aleatoric_ones_soon():
    """Every draw 0.9 ahead (a confident frame), or every draw 0.55 / 0.40 (labels that overlap: each draw's vote
    agrees, the margin is small but never negative)."""
    assert settles(np.full(CAP, 0.9)) and ModeTest(GAMMA).stake() == 0.0
    test = ModeTest(GAMMA)
    test.observe(np.full(LOOK, 0.9))
    assert test.update(np.full(LOOK, 0.9)) and test.stakes == [MAX_STAKE]
    test = ModeTest(GAMMA)
    test.observe(np.full(LOOK, 0.15))
    looks = next(j for j in range(1, 40) if test.update(np.full(LOOK, 0.15)))
    assert looks <= 4  # 32 draws: a stake of 0.8 grows the wealth 12 % a draw


def test_margins_are_the_candidate_against_the_best_other_class():
    probs = np.array([[0.6, 0.3, 0.1], [0.2, 0.5, 0.3], [0.4, 0.4, 0.2]])
    assert np.allclose(margins(probs, 0), [0.3, -0.3, 0.0]) and np.allclose(margins(probs, 2), [-0.5, -0.2, -0.2])


def test_a_stake_is_fixed_before_its_look_is_seen():
    test = ModeTest(GAMMA)
    test.observe(np.array([0.5, -0.5]))  # mean 0: no stake
    assert not test.update(np.array([1.0, 1.0])) and test.log_wealth == 0.0
    assert test.stakes == [0.0] and test.stake() > 0
