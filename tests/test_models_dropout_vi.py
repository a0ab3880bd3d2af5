"""Concrete dropout (learned rates, Bernoulli test masks) and the VI head (closed-form KL, local reparameterisation)."""

import pytest
import torch
from torch.distributions import Normal, kl_divergence
from torch.nn.functional import cross_entropy, softplus

from uqdrive.data.binning import SteeringBins
from uqdrive.models.concrete_dropout import ConcreteDropout
from uqdrive.models.mcd import MCDPosterior
from uqdrive.models.pilotnet import Architecture, init_weights
from uqdrive.models.vi import VIPosterior

SMALL = Architecture(conv=(2, 2, 2, 2, 2), features=6, hidden=(5, 4, 4))
THREE = SteeringBins(per_unit=1)  # 3 classes


def test_concrete_dropout_rate_is_learned_and_stays_a_probability():
    g = torch.Generator().manual_seed(0)
    x = torch.randn((512, 20), generator=g)
    y = (x[:, :3].sum(1) > 0).long()
    layer, drop = torch.nn.Linear(20, 2), ConcreteDropout(20, init_p=0.1)
    optimizer = torch.optim.Adam([*layer.parameters(), *drop.parameters()], lr=0.05)
    for _ in range(150):
        loss = cross_entropy(layer(drop.relaxed(x, g)), y) + drop.regularizer(layer, 1e-4**2 / 512, 2 / 512)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    p = drop.p.item()
    assert abs(p - 0.1) > 0.02 and 0 < p < 1


def test_test_time_masks_are_bernoulli_with_the_learned_rate():
    drop = ConcreteDropout(50, init_p=0.3)
    masks = drop.sample_masks(2000, torch.Generator().manual_seed(0))
    assert masks.shape == (2000, 1, 50)
    assert masks.unique().tolist() == pytest.approx([0.0, 1 / 0.7])
    assert abs(float((masks == 0).float().mean()) - 0.3) < 0.01


def test_mcd_rejects_rates_outside_zero_one():
    with pytest.raises(ValueError, match="model.init_p=1.0"):
        MCDPosterior(SMALL, THREE, init_p=1.0)


def vi_head(generator):
    mcd = init_weights(MCDPosterior(SMALL, THREE), generator)
    vi = VIPosterior.from_mcd(mcd, prior_sigma=0.7, init_sigma=0.2)
    with torch.no_grad():
        for rho in [*vi.w_rho, *vi.b_rho]:
            rho.add_(0.3 * torch.randn(rho.shape, generator=generator))
    return vi


def test_vi_kl_is_the_closed_form_gaussian_kl():
    vi = vi_head(torch.Generator().manual_seed(0))
    prior = Normal(0.0, 0.7)
    expected = sum(
        kl_divergence(Normal(mu, softplus(rho)), prior).sum()
        for mu, rho in zip([*vi.w_mu, *vi.b_mu], [*vi.w_rho, *vi.b_rho])
    )
    torch.testing.assert_close(vi.kl(), expected)


def test_vi_local_reparameterisation_matches_sampling_the_weights():
    """For one frame, drawing pre-activations (LRT) has the same law as drawing whole weight matrices."""
    g = torch.Generator().manual_seed(1)
    vi = vi_head(g)
    features = torch.rand((1, 6), generator=g)
    n = 40000
    lrt = vi.head_logits(features, n, g)[:, 0].detach()
    h = features
    for k, (w_mu, b_mu, w_rho, b_rho) in enumerate(zip(vi.w_mu, vi.b_mu, vi.w_rho, vi.b_rho)):
        w = w_mu + softplus(w_rho) * torch.randn((n, *w_mu.shape), generator=g)
        b = b_mu + softplus(b_rho) * torch.randn((n, *b_mu.shape), generator=g)
        h = torch.matmul(h if k == 0 else torch.relu(h), w) + b.unsqueeze(1)
    weights = h[:, 0].detach()
    scale = weights.std(0)
    assert torch.all((lrt.mean(0) - weights.mean(0)).abs() < 0.05 * scale)
    torch.testing.assert_close(lrt.std(0), scale, rtol=0.05, atol=0)


@pytest.mark.parametrize("change", ["optimiser step", "loaded state"])
def test_vi_inference_moments_follow_every_change_of_the_parameters(change):
    """head_probs reuses the variances softplus(ρ)² between calls; after the parameters change in place (a training
    step, a loaded checkpoint) it must draw what the uncached computation draws, bit for bit."""
    vi = VIPosterior(SMALL, THREE, init_sigma=0.1)
    features = torch.randn((2, SMALL.features), generator=torch.Generator().manual_seed(1))

    def both(seed: int) -> tuple[torch.Tensor, torch.Tensor]:
        cached = vi.head_probs(features, 5, torch.Generator().manual_seed(seed))
        with torch.no_grad():
            fresh = torch.softmax(vi.head_logits(features, 5, torch.Generator().manual_seed(seed)), -1)
        return cached, fresh

    cached, fresh = both(0)
    assert torch.equal(cached, fresh)
    if change == "optimiser step":
        optimizer = torch.optim.SGD(vi.head_parameters(), lr=1.0)
        vi.head_logits(features, 1, torch.Generator().manual_seed(2)).sum().backward()
        optimizer.step()
    else:
        state = {k: v + 0.5 if "rho" in k else v for k, v in vi.state_dict().items()}
        vi.load_state_dict(state)
    after, fresh_after = both(0)
    assert torch.equal(after, fresh_after) and not torch.equal(after, cached)
