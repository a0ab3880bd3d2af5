"""The HMC kernel against a posterior known in closed form (Bayesian linear regression), and split-R̂."""

import pytest
import torch

from uqdrive.models.mcmc import hmc, split_rhat


def linear_regression(n: int = 40, noise: float = 0.5, prior: float = 2.0):
    """Data, log-density/gradient and exact Gaussian posterior (mean, covariance) of y = Xβ + ε."""
    g = torch.Generator().manual_seed(0)
    x = torch.randn((n, 3), generator=g, dtype=torch.float64)
    x[:, 2] = x[:, 1] + 0.3 * x[:, 2]  # correlated columns → correlated posterior
    beta = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
    y = x @ beta + noise * torch.randn(n, generator=g, dtype=torch.float64)
    precision = x.T @ x / noise**2 + torch.eye(3, dtype=torch.float64) / prior**2
    cov = torch.linalg.inv(precision)
    mean = cov @ x.T @ y / noise**2

    def log_prob_grad(theta):
        resid = y - theta.double() @ x.T  # [chains, n]
        lp = -0.5 * resid.square().sum(1) / noise**2 - 0.5 * theta.double().square().sum(1) / prior**2
        grad = resid @ x / noise**2 - theta.double() / prior**2
        return lp.float(), grad.float()

    return log_prob_grad, mean.float(), cov.float()


@pytest.mark.parametrize("adapt_mass", [False, True])
def test_hmc_matches_the_analytic_posterior_of_bayesian_linear_regression(adapt_mass):
    log_prob_grad, mean, cov = linear_regression()
    init = torch.zeros(4, 3)
    result = hmc(
        log_prob_grad,
        init,
        num_samples=1000,
        warmup=300,
        leapfrog_steps=10,
        step_size=0.5,
        target_accept=0.75,
        adapt_mass=adapt_mass,
        generator=torch.Generator().manual_seed(1),
    )
    samples = result.samples  # [4, 1000, 3]
    assert samples.shape == (4, 1000, 3)
    assert 0.6 < float(result.accept_rate.mean()) < 0.95  # adapted to the 0.75 target
    # Monte-Carlo standard error of the mean from 20 batch means per chain (accounts for autocorrelation)
    batch_means = samples.reshape(4, 20, 50, 3).mean(2).reshape(80, 3)
    mcse = batch_means.std(0) / 80**0.5
    assert torch.all((samples.reshape(-1, 3).mean(0) - mean).abs() < 4 * mcse + 1e-3)
    flat = samples.reshape(-1, 3)
    sample_cov = torch.cov(flat.T)
    torch.testing.assert_close(sample_cov.diagonal(), cov.diagonal(), rtol=0.15, atol=0)
    corr = cov[1, 2] / (cov[1, 1] * cov[2, 2]).sqrt()
    sample_corr = sample_cov[1, 2] / (sample_cov[1, 1] * sample_cov[2, 2]).sqrt()
    assert abs(float(sample_corr - corr)) < 0.05
    assert float(split_rhat(samples).max()) < 1.05


def test_hmc_is_reproducible_and_thins():
    log_prob_grad, _, _ = linear_regression()

    def run():
        return hmc(
            log_prob_grad,
            torch.zeros(2, 3),
            num_samples=5,
            warmup=10,
            thin=3,
            generator=torch.Generator().manual_seed(5),
        )

    a, b = run(), run()
    assert a.samples.shape == (2, 5, 3) and torch.equal(a.samples, b.samples)
    assert a.log_prob.shape == (2, 5)


def test_hmc_rejects_bad_settings_and_a_bad_start():
    log_prob_grad, _, _ = linear_regression()
    with pytest.raises(ValueError, match="thin=0"):
        hmc(log_prob_grad, torch.zeros(2, 3), num_samples=5, warmup=0, thin=0)
    with pytest.raises(ValueError, match="target_accept=1.2"):
        hmc(log_prob_grad, torch.zeros(2, 3), num_samples=5, warmup=0, target_accept=1.2)
    with pytest.raises(ValueError, match="not finite at the initial point"):
        hmc(log_prob_grad, torch.full((2, 3), float("nan")), num_samples=5, warmup=0)


def test_split_rhat_is_one_for_mixed_chains_and_large_for_stuck_ones():
    g = torch.Generator().manual_seed(0)
    mixed = torch.randn((4, 500, 2), generator=g)
    assert float(split_rhat(mixed).max()) < 1.02
    stuck = mixed + torch.tensor([0.0, 3.0, 0.0, 3.0]).view(4, 1, 1)
    assert float(split_rhat(stuck).min()) > 1.5
    drifting = mixed + torch.linspace(0, 5, 500).view(1, 500, 1)  # each chain's halves disagree
    assert float(split_rhat(drifting).min()) > 1.3
    assert split_rhat(mixed[..., 0]).shape == ()


def test_settled_iteration_is_where_loss_and_nll_come_within_three_sd_of_their_kept_mean():
    from uqdrive.models.hmc import settled_iteration

    losses = [5.0, 3.0, 1.2, 1.0, 1.1, 0.9, 1.05, 1.0, 0.95, 1.1]  # kept: mean 1.0, sd 0.079 → band [0.76, 1.24]
    curve = [
        {"step": 10 * (i + 1), "train_loss": v, "val_nll": 2.0, "warmup": int(i < 5)} for i, v in enumerate(losses)
    ]
    assert settled_iteration(curve) == 30  # 3.0 at step 20 is the last value outside the band
    curve[3]["val_nll"] = 9.0  # the predictive still drifting at step 40
    assert settled_iteration(curve) == 50


def head_problem(frames: int = 120, seed: int = 0):
    """TrainingData of a small random MCD model whose trunk features are given: labels from a random linear teacher."""
    from pathlib import Path

    from uqdrive.data.binning import SteeringBins
    from uqdrive.data.datasets import FrameSet
    from uqdrive.models.mcd import MCDPosterior
    from uqdrive.models.pilotnet import Architecture, init_weights
    from uqdrive.models.training import TrainingData

    g = torch.Generator().manual_seed(seed)
    bins = SteeringBins(low=-0.2, high=0.2)
    arch = Architecture(conv=(2, 2, 2, 2, 2), features=8, hidden=(8, 6, 6))
    base = init_weights(MCDPosterior(arch, bins), g).eval()
    teacher = torch.randn((arch.features, bins.num_classes), generator=g)

    def split(n: int, name: str) -> tuple[FrameSet, torch.Tensor]:
        features = torch.rand((n, arch.features), generator=g)
        labels = (features @ teacher + 0.3 * torch.randn((n, bins.num_classes), generator=g)).argmax(1)
        return FrameSet(torch.zeros((n, 48, 64), dtype=torch.uint8), labels, bins.num_classes, name), features

    (train, train_features), (val, val_features) = split(frames, "train"), split(frames // 2, "val")
    data = TrainingData(train, val, bins, arch, Path("unused-mcd.pt"), eval_samples=5)
    data.base, data.train_features, data.val_features = base, train_features, val_features  # the cached inputs
    return data


@pytest.mark.parametrize(("metric", "layers"), [("laplace", 1), ("diagonal", 2)])
def test_hmc_fit_is_a_function_of_its_seed(metric, layers):
    """Model files and cell identities rely on it: same seed, same samples, curve and metrics; another seed differs."""
    from uqdrive.models.hmc import HMCPosterior, HMCSettings

    data = head_problem()
    settings = HMCSettings(chains=4, samples=4, warmup=6, metric=metric, bayesian_layers=layers, map_epochs=1)

    def fit(seed: int):
        fitted = HMCPosterior.fit(settings, data, torch.Generator().manual_seed(seed))
        return fitted.posterior.state_dict(), fitted.curve, fitted.extra

    (first, curve, extra), (again, curve_again, extra_again) = fit(0), fit(0)
    assert first.keys() == again.keys() and all(torch.equal(first[k], again[k]) for k in first)
    assert curve == curve_again and extra == extra_again
    assert first["samples"].shape == (4 * 4, sum(i * o + o for i, o in data.arch.head_shapes(5)[-layers:]))
    assert extra["kept_samples"] == 16 and extra["chains"] == 4 and curve[-1]["step"] == 6 + 4
    assert not torch.equal(first["samples"], fit(1)[0]["samples"])


@pytest.mark.parametrize("layers", [1, 4])
def test_head_nll_is_the_summed_cross_entropy_of_each_head(layers):
    """Its classes-first log-sum-exp (`head_nll`) is torch's cross-entropy, shared or per-head features alike."""
    from torch.nn.functional import cross_entropy

    from uqdrive.models.heads import head_nll, head_size, unflatten
    from uqdrive.models.pilotnet import sampled_mlp_logits

    g = torch.Generator().manual_seed(0)
    shapes = [(12, 9), (9, 8), (8, 8), (8, 5)][-layers:]
    theta = torch.randn((3, head_size(shapes)), generator=g, dtype=torch.float64)
    for features, labels in [
        (torch.randn((40, shapes[0][0]), generator=g, dtype=torch.float64), torch.randint(0, 5, (40,), generator=g)),
        (
            torch.randn((3, 40, shapes[0][0]), generator=g, dtype=torch.float64),
            torch.randint(0, 5, (3, 40), generator=g),
        ),
    ]:
        logits = sampled_mlp_logits(features, unflatten(theta, shapes))
        expected = torch.stack([cross_entropy(logits[k], labels.expand(3, -1)[k], reduction="sum") for k in range(3)])
        torch.testing.assert_close(head_nll(features, labels, theta, shapes), expected)
