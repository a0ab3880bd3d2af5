"""The rare-failure suite: each world's exact failure probability against simulation and against code independent
of it (path enumeration, `scipy.integrate.quad`); fixed splitting's estimate unbiased at a fixed condition; and
every world's refutation error at the null boundary by simulation, with the Clopper–Pearson upper limit of the
error below γ, for the method the bench uses on it (and importance sampling on the walk too). A splitting mutant
that forgets the weights fails the same check."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import integrate, stats

from uqdrive.bench.rare_bench import MIXTURE, splits
from uqdrive.bench.rare_suite import WalkWorld, suite, walk_failure
from uqdrive.uq.rare import RareSettings, refute
from uqdrive.uq.rare_splitting import Splitting, refute_by_splitting, tree_estimates

GAMMA = 0.05
WORLDS = suite()
NAMES = [w.name for w in WORLDS]
SPLITTING = Splitting((0.2, 0.4, 0.6, 0.8), 4)


def cp_upper(errors: int, runs: int) -> float:
    return float(stats.beta.ppf(0.975, errors + 1, runs - errors)) if errors < runs else 1.0


@pytest.mark.parametrize("world", WORLDS, ids=NAMES)
def test_each_worlds_exact_failure_probability_matches_simulation(world) -> None:
    placed = world.at(5e-3)
    assert placed.failure_probability() == pytest.approx(5e-3, rel=1e-9)
    assert world.at(1e-3).failure_probability() == pytest.approx(1e-3, rel=1e-9)
    n = 200_000
    points = placed.domain.sample(np.random.default_rng(3), 1, n)
    failed, margins = placed(points, np.arange(n)[None] + 7 * 10**9)
    assert abs(failed.mean() - 5e-3) < 4.5 * np.sqrt(5e-3 / n), failed.mean()  # 4.5 SE: 1 in 10⁵ to fail by chance
    assert (margins[failed] <= 0).all() and (margins[~failed] >= 0).all()


def test_the_walk_failure_is_exact_against_enumerating_every_path() -> None:
    steps, level = 9, 3
    paths = np.array(list(itertools.product((1, -1), repeat=steps)))
    hits = np.cumsum(paths, 1).max(1) >= level
    ups = (paths == 1).sum(1)
    for up in (0.1, 0.3, 0.55):
        exact = float(np.sum(hits * up**ups * (1 - up) ** (steps - ups)))
        assert walk_failure(up, steps, level)[0] == pytest.approx(exact, abs=1e-15)
    walk = next(w for w in WORLDS if isinstance(w, WalkWorld)).at(1e-3)
    slice_ = lambda x: stats.beta.pdf(x, 2, 5) * walk_failure(walk.low + walk.size * x, 40, 10)[0]  # noqa: E731
    assert integrate.quad(slice_, 0, 1, epsabs=1e-15, epsrel=1e-12)[0] == pytest.approx(1e-3, rel=1e-9)


def test_splittings_tree_estimate_is_unbiased_and_at_most_one() -> None:
    walk = next(w for w in WORLDS if isinstance(w, WalkWorld)).at(1e-3)
    point = np.array([[0.6, 0.2]])
    x, cost = tree_estimates(walk, np.repeat(point, 40_000, 0), SPLITTING, np.random.default_rng(4))
    exact = walk_failure(walk.low + walk.size * 0.6, walk.steps, walk.level)[0]
    assert x.max() <= 1 and cost.min() >= 0.025  # a tree costs at least one step
    assert abs(x.mean() - exact) < 4.5 * x.std() / np.sqrt(x.size), (x.mean(), exact)
    with pytest.raises(ValueError, match=r"^splitting.levels=\[0.5, 0.4\] must increase strictly within \(0, 1\)$"):
        Splitting((0.5, 0.4), 3)


NULL_M, NULL_RUNS, NULL_BUDGET = 1e-2, 2_000, 300  # at m = 10⁻² every world sees failures within the budget


def null_errors(
    world, split: bool, seed: int, splitting: Splitting = SPLITTING, mixture: bool = False
) -> tuple[int, float]:
    """(false refutations of η1 ≥ 1 − m in NULL_RUNS runs, the world put at p = m; mean failures a run)."""
    placed = world.at(NULL_M)
    tuning = MIXTURE if mixture else {}
    settings = RareSettings(target=1 - NULL_M, gamma=GAMMA, refute_budget=NULL_BUDGET, certify_budget=10**6, **tuning)
    rng = np.random.default_rng(seed)
    if split:
        run = refute_by_splitting(placed, placed.domain, settings, splitting, rng, runs=NULL_RUNS)
        return int(run.refuted.sum()), float("nan")
    run = refute(placed, placed.domain, settings, rng, runs=NULL_RUNS, record_runs=0, seed=seed * 10**10)
    return int(run.refuted.sum()), float(run.failures.mean())


CASES = [(w, False) for w in WORLDS] + [(w, True) for w in WORLDS if splits(w)]


@pytest.mark.parametrize(("world", "split"), CASES, ids=[f"{w.name}-{'split' if s else 'IS'}" for w, s in CASES])
def test_every_worlds_refutation_errs_below_gamma_at_the_null_boundary(world, split: bool) -> None:
    errors, failures = null_errors(world, split, seed=CASES.index((world, split)))
    assert cp_upper(errors, NULL_RUNS) < GAMMA, errors
    assert split or failures >= 1  # the runs see failures: the check is not passed by seeing nothing


MIXED = [w for w in WORLDS if w.name.startswith(("16 modes", "corner (shipped)", "corner, outcome", "walk, margin"))]


@pytest.mark.slow
@pytest.mark.parametrize("world", MIXED, ids=[w.name for w in MIXED])
def test_the_mixture_proposals_refutation_errs_below_gamma_at_the_null_boundary(world) -> None:
    """The bench's 16-component mixture (`rare_bench.MIXTURE`) on the world it was chosen for and three it was not
    (each ~20 s: every world would be 4 minutes; the bench's --mixture checks all at its own null runs)."""
    errors, failures = null_errors(world, False, seed=500 + MIXED.index(world), mixture=True)
    assert cp_upper(errors, NULL_RUNS) < GAMMA and failures >= 1, (errors, failures)


def test_splitting_that_forgets_its_weights_fails_the_same_check(monkeypatch: pytest.MonkeyPatch) -> None:
    """The mutant counts a failed particle at level k as factor^k of them (capped at 1): biased upward, so at the
    null boundary it refutes far more often than γ, the lower Clopper–Pearson limit above γ."""
    import uqdrive.uq.rare_splitting as module

    honest = module.tree_estimates

    def unweighted(world, points, splitting, rng):
        x, cost = honest(world, points, splitting, rng)
        return np.minimum(x * splitting.factor ** len(splitting.levels), 1.0), cost  # weights dropped (capped at 1)

    monkeypatch.setattr(module, "tree_estimates", unweighted)
    walk = next(w for w in WORLDS if splits(w))
    errors, _ = null_errors(walk, True, seed=99)
    assert stats.beta.ppf(0.025, errors, NULL_RUNS - errors + 1) > GAMMA, errors
