"""Rare events over a domain: the certification path's exact error (computed here by a dynamic program over
failure counts, independent of `uqdrive.uq.stopping`), bad input refused in one line before any rollout, the
domain over the envelope's condition space, failure records that re-drive, and the lower confidence bound."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from uqdrive.bench.rare_world import DOMAIN, CornerWorld
from uqdrive.envelope.domain import Domain, DomainSettings
from uqdrive.envelope.space import Axis, ConditionSpace
from uqdrive.schema import ConfigError, validate
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import ScenarioConfig, WeatherConfig
from uqdrive.uq.rare import (
    RareSettings,
    certification_test,
    failure_estimate,
    failure_lower_bound,
    floor_rollouts,
    refutation_floor,
    refute,
    zero_failure_rollouts,
)
from uqdrive.uq.rare_proposal import BetaMixture, ProductBeta, mixture_sample, mixture_step

CONF = Path(__file__).resolve().parents[1] / "conf"


def certify_errors(test, failure_rates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P(certified above), P(refuted below)) at each failure probability, by a forward pass over the failure
    count of the runs still going: between looks the new failures are Binomial(Δn, p), convolved in."""
    above, below = np.zeros(failure_rates.size), np.zeros(failure_rates.size)
    for r, p in enumerate(failure_rates):
        alive, drawn = np.ones(1), 0  # alive[f]: P(still going with f failures)
        for n in test.looks:
            step = stats.binom.pmf(np.arange(n - drawn + 1), n - drawn, p)
            alive, drawn = np.convolve(alive, step), n
            codes = np.array([{"above": 1, "below": -1, None: 0}[test.decide(n - f, n)] for f in range(alive.size)])
            above[r] += alive[codes == 1].sum()
            below[r] += alive[codes == -1].sum()
            alive = np.where(codes == 0, alive, 0.0)
            alive = alive[: np.flatnonzero(alive)[-1] + 1] if alive.any() else alive[:1] * 0
    return above, below


@pytest.mark.parametrize(("target", "budget"), [(1 - 1e-3, 12_000), (1 - 1e-4, 100_000)])
def test_certification_errs_at_most_gamma_and_needs_the_zero_failure_floor(target: float, budget: int) -> None:
    settings = RareSettings(target=target, gamma=0.05, certify_budget=budget)
    test = certification_test(settings)
    eps = 1 - target
    rates = eps * np.array([1.0, 1.0 + 1e-9, 1.5, 3.0])  # at and above m: "above" is the error
    above, _ = certify_errors(test, rates)
    assert above.max() <= 0.05 + 1e-12 and above[0] >= 0.7 * 0.05  # γ is spent (as far as the counts allow)
    np.testing.assert_allclose(above, test.operating_characteristics(1 - rates)[0], atol=1e-9)
    _, below = certify_errors(test, eps * np.array([1.0, 0.5, 0.1]))  # at and below m: "below" is the error
    assert below.max() <= 0.05 + 1e-12
    zero = zero_failure_rollouts(test)
    floor = floor_rollouts(target, 0.05)
    assert target**floor <= 0.05 < target ** (floor - 1)
    assert abs(floor - math.log(1 / 0.05) / eps) / floor < 1e-3  # the floor ≈ ln(1/γ)/ε
    assert zero == test.looks[0] == math.ceil(1.2 * floor)  # the later looks' share of γ costs 20 %


def test_the_floor_is_ln_1_over_gamma_over_ln_1_over_1_minus_eps_not_ln_1_over_gamma_over_eps() -> None:
    """ε = 0.1, γ = 0.05: "certify iff 29 of 29 safe" errs 0.9²⁹ = 0.047 ≤ γ at p = ε (a binomial sum here, the
    worst p ≥ ε being ε) with N = 29 < ln(1/γ)/ε = 29.96, so ln(1/γ)/ε is no lower bound; the floor the project
    uses is the least n with (1 − ε)^n ≤ γ, i.e. ln(1/γ)/ln(1/(1 − ε)) rounded up."""
    eps, gamma, n = 0.1, 0.05, 29
    errors = [stats.binom.pmf(0, n, p) for p in (eps, 0.15, 0.5)]
    assert max(errors) == pytest.approx(0.0471013, abs=1e-6) and max(errors) <= gamma
    assert n < math.log(1 / gamma) / eps and math.log(1 / gamma) / eps == pytest.approx(29.957, abs=1e-3)
    bound = math.log(1 / gamma) / math.log(1 / (1 - eps))
    assert bound == pytest.approx(28.433, abs=1e-3) and bound <= n
    assert floor_rollouts(1 - eps, gamma) == n and stats.binom.pmf(0, n - 1, eps) > gamma
    floor = floor_rollouts(1 - 1e-4, gamma)  # at ε = 10⁻⁴: 29,956, and certifying after zero failures costs 1.2×
    zero = zero_failure_rollouts(certification_test(RareSettings(target=1 - 1e-4, certify_budget=4 * floor)))
    assert (floor, zero) == (29_956, 35_948) and zero / floor == pytest.approx(1.2, abs=1e-4)


@pytest.mark.parametrize(
    ("section", "message"),
    [
        ({"defensive": 0.0}, "rare.defensive=0.0"),
        ({"defensive": 1.5}, "rare.defensive=1.5"),
        (
            {"refute_budget": 6, "target": 0.5, "defensive": 1.0},
            "rare.refute_budget=6 no run can refute eta1 >= 0.5 at gamma=0.05 with defensive=1.0 in fewer than 7 "
            "rollouts",
        ),
        (
            {"certify_budget": 1_000},
            "rare.certify_budget=1000 cannot certify eta1 >= 0.9999 at gamma=0.05 even "
            "with zero failures: that needs 29956 rollouts",
        ),
        ({"components": 4, "smoothing": 0.7}, "rare.smoothing=0.7 must be 1 with components=4"),
    ],
)
def test_bad_settings_are_one_line_naming_the_key_and_value(section: dict, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        validate(RareSettings, section, "rare")
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def space() -> ConditionSpace:
    base = Condition(
        ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout.yaml"),
        WeatherConfig.from_yaml(CONF / "weather" / "clear_noon.yaml"),
        0.0,
    )
    return ConditionSpace((Axis("noise", 0.0, 0.2), Axis("scenario.ring_radius", 18.0, 26.0)), base)


def domain_settings(noise_range: list[float]) -> DomainSettings:
    axes = [
        {"key": "scenario.ring_radius", "range": [18.0, 26.0]},
        {"key": "noise", "range": noise_range, "shape": [2.0, 5.0]},
    ]
    return validate(DomainSettings, {"axes": axes}, "domain")


def test_the_domain_is_a_density_over_the_envelopes_condition_space() -> None:
    domain = Domain.of(domain_settings([0.0, 0.2]), space())
    np.testing.assert_array_equal(domain.nominal.a, [2.0, 1.0])  # in the space's axis order
    point = domain.sample(np.random.default_rng(0), 3)[0]
    world = domain.condition(point)
    assert world.noise == pytest.approx(0.2 * point[0]) and world.scenario.ring_radius == pytest.approx(
        18 + 8 * point[1]
    )
    with pytest.raises(
        ConfigError, match=r"^domain.axes\[1\].range=\[0.0, 0.1\]: the density is zero on part of noise"
    ):
        Domain.of(domain_settings([0.0, 0.1]), space())
    with pytest.raises(ValueError, match=r"^domain.noise: density zero on part of \[0, 1\]"):
        nominal, everywhere = ProductBeta.of([2.0], [5.0], 0.0, 0.5), ProductBeta.of([1.0], [1.0])
        refute(_no_world, nominal, RareSettings(), np.random.default_rng(0), proposal=everywhere, names=("noise",))


def _no_world(points: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    raise AssertionError("a rollout ran before the input was checked")


class ConstantMargin:
    """A world whose margin never varies: nothing for the cross-entropy step to adapt on."""

    margin = "constant"

    def __call__(self, points: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _no_world(points, seeds)


def test_a_constant_margin_is_refused_before_any_rollout_and_the_budget_floor_is_exact() -> None:
    with pytest.raises(ValueError, match=r"^world.margin=constant: the cross-entropy step has nothing to adapt on; "):
        refute(ConstantMargin(), DOMAIN, RareSettings(), np.random.default_rng(0))
    # a lower bound on any run: even a failure at every rollout (half-Kelly stakes, not the cap) refutes no sooner
    settings = RareSettings(target=0.5, defensive=1.0, refute_budget=50)
    always = lambda points, seeds: (np.ones(seeds.shape, bool), -np.ones(seeds.shape))  # noqa: E731
    run = refute(always, DOMAIN, settings, np.random.default_rng(0), adapt=False)
    assert run.refuted[0] and run.rollouts[0] >= refutation_floor(0.5, 0.05, 1.0) == 7


def test_failures_come_back_as_records_that_re_drive_them_and_the_bound_is_below_p() -> None:
    world = CornerWorld.at(1e-3, DOMAIN)
    run = refute(world, DOMAIN, RareSettings(target=1 - 1e-4), np.random.default_rng(5))
    assert run.refuted[0] and run.failures[0] == len(run.records) > 0
    points = np.array([[r.point for r in run.records]])
    failed, margins = world(points, np.array([[r.seed for r in run.records]]))
    assert failed.all() and (margins <= 0).all()
    assert [r.seed for r in run.records] == sorted(r.seed for r in run.records)
    stopped = run.observations[0, : run.rollouts[0]]
    assert 1e-4 < failure_lower_bound(stopped, 0.05) <= 1e-3  # refuted at m = 1e-4, and still below p
    bounds = [failure_lower_bound(o[:n], 0.05) for o, n in zip(*_runs(world, 300))]
    assert np.mean(np.array(bounds) > 1e-3) <= 0.05


def _runs(world: CornerWorld, runs: int) -> tuple[np.ndarray, np.ndarray]:
    settings = RareSettings(target=1 - 1e-3, refute_budget=200)  # at the boundary: the bound is tested hardest
    run = refute(world, DOMAIN, settings, np.random.default_rng(9), runs=runs, record_runs=0)
    return run.observations, run.rollouts


def two_modes() -> BetaMixture:
    """Two components on [0, 1]² (weights 0.3 / 0.7) for one run."""
    a = np.array([[[20.0, 2.0], [2.0, 20.0]]])
    b = np.array([[[2.0, 20.0], [20.0, 2.0]]])
    return BetaMixture(a, b, np.array([[0.3, 0.7]]), np.zeros(2), np.ones(2))


def test_a_mixture_proposals_density_is_its_samplers_so_the_weights_are_unbiased() -> None:
    """The refutation's validity rests on w = nominal/q with q the density the points were drawn from. Here q's
    log-density against the components' Beta pdfs summed by scipy, and by simulation E_q[w · 1{c ∈ A}] = the
    nominal's mass of A (exact by scipy's CDFs) for the defensive mixture with a two-component proposal."""
    mixture, nominal = two_modes(), ProductBeta.of([2.0, 2.0], [5.0, 5.0])
    points = np.array([[[0.9, 0.1], [0.2, 0.8], [0.5, 0.5]]])
    by_hand = sum(
        mixture.weights[0, k]
        * stats.beta.pdf(points[0, :, 0], mixture.a[0, k, 0], mixture.b[0, k, 0])
        * stats.beta.pdf(points[0, :, 1], mixture.a[0, k, 1], mixture.b[0, k, 1])
        for k in range(2)
    )
    assert np.exp(mixture.log_pdf(points))[0] == pytest.approx(by_hand, rel=1e-9)
    drawn, weights = mixture_sample(nominal, mixture, 0.1, np.random.default_rng(5), 1, 400_000)
    inside = (drawn[0, :, 0] > 0.6) & (drawn[0, :, 1] < 0.3)  # where the first component sits, the nominal rarely
    x = weights[0] * inside
    exact = stats.beta.sf(0.6, 2, 5) * stats.beta.cdf(0.3, 2, 5)
    assert abs(x.mean() - exact) < 4.5 * x.std() / np.sqrt(x.size), (x.mean(), exact)
    assert weights.max() <= 1 / 0.1 + 1e-9 and abs(weights.mean() - 1) < 4.5 * weights.std() / np.sqrt(weights.size)
    share = (drawn[0, :, 0] > drawn[0, :, 1]).mean()  # the first component's points, and λ's nominal ones
    assert abs(share - (0.9 * 0.3 + 0.1 * 0.5)) < 0.01


def test_the_mixture_step_puts_a_component_on_each_separate_failure_mode() -> None:
    """Elite points in two far clusters (30 % near (0.9, 0.1), 70 % near (0.1, 0.9)): two components, one on each,
    weighted by the clusters' shares; a run with no elite keeps its law."""
    rng = np.random.default_rng(2)
    near = lambda c, k: np.clip(c + 0.02 * rng.standard_normal((k, 2)), 0, 1)  # noqa: E731
    points = np.concatenate([near([0.9, 0.1], 30), near([0.1, 0.9], 70), rng.random((100, 2)) * 0.2 + 0.4])[None]
    margins = np.concatenate([-np.ones(100), np.ones(100)])[None]  # the clusters failed, the middle did not
    start = BetaMixture.copies(ProductBeta.of([2.0, 2.0], [2.0, 2.0]), 2, 1)
    fitted = mixture_step(start, points, margins, np.ones((1, 200)), elite=0.1)
    means = fitted.a[0] / (fitted.a[0] + fitted.b[0])
    order = np.argsort(means[:, 0])  # the (0.1, 0.9) component first
    assert means[order[0]] == pytest.approx([0.1, 0.9], abs=0.03) and means[order[1]] == pytest.approx(
        [0.9, 0.1], abs=0.03
    )
    assert fitted.weights[0, order] == pytest.approx([0.7, 0.3])
    kept = mixture_step(start, points, np.ones((1, 200)), np.ones((1, 200)), elite=0.1)  # ±1 tie, no failure
    assert np.array_equal(kept.a, start.a) and np.array_equal(kept.weights, start.weights)


def test_a_weight_where_the_proposal_density_underflows_is_exactly_one_over_lambda():
    """A nominal draw far outside a concentrated proposal: g underflows to 0, so q = λ·f and the weight is 1/λ — in
    floating point exp(−log 0.1) is 10.000000000000002, which the betting interval on [0, 1/λ] refused (a stage run
    crashed after refuting)."""
    nominal = ProductBeta.of([1.0, 1.0], [1.0, 2.8], [0.0, 0.0], [1.0, 1.0])  # the real world's blend law
    proposal = ProductBeta.of([5000.0, 5000.0], [1.0, 1.0], [0.0, 0.0], [1.0, 1.0])  # all its mass at the corner
    _, weights = mixture_sample(nominal, proposal, 0.1, np.random.default_rng(0), 1, 2_000)
    assert weights.max() <= 10.0 and (weights > 9.99).sum() > 100  # 11 of them were 10 + 2e-15
    failure_estimate(weights[0], 0.1, 0.05)  # every value in [0, 1/λ]
