"""Function-space convergence diagnostics (ArviZ R̂ / ESS over predictive probabilities and per-frame MI)."""

import pytest
import torch

from uqdrive.models.diagnostics import between_chain_mi_share, function_space_diagnostics, per_draw_mutual_information


def chain_probs(
    logit_means: torch.Tensor, draws: int, frames: int = 30, classes: int = 5, seed: int = 0
) -> torch.Tensor:
    """Independent draws [chains, draws, frames, classes]: softmax of N(frame logits + chain offset, 1)."""
    g = torch.Generator().manual_seed(seed)
    base = 2 * torch.randn((1, 1, frames, classes), generator=g)
    offset = logit_means.view(-1, 1, 1, 1) * torch.tensor([1.0] + [0.0] * (classes - 1))
    noise = torch.randn((len(logit_means), draws, frames, classes), generator=g)
    return torch.softmax(base + offset + noise, -1)


def test_rhat_is_near_one_for_chains_of_one_distribution_and_large_for_two():
    same = function_space_diagnostics(chain_probs(torch.zeros(4), 200))
    assert 0.99 < same["fs_rhat_median"] < 1.02 and same["fs_rhat_max"] < 1.1
    assert same["fs_rhat_share_ok"] == 1.0 and same["mi_rhat_max"] < 1.1
    assert same["fs_ess_bulk_min"] > 400 and same["fs_ess_tail_min"] > 300  # 800 independent draws
    split = function_space_diagnostics(chain_probs(torch.tensor([0.0, 0.0, 3.0, 3.0]), 200))
    assert split["fs_rhat_median"] > 1.1 and split["fs_rhat_share_ok"] < 0.5
    assert split["mi_rhat_max"] > 1.1


def test_pairs_below_the_probability_floor_are_left_out():
    probs = chain_probs(torch.zeros(4), 50)
    probs[..., -1] = 1e-5  # a class no draw believes in
    probs = probs / probs.sum(-1, keepdim=True)
    d = function_space_diagnostics(probs)
    assert d["fs_pairs"] <= 30 * 4


def test_mean_per_draw_kl_is_the_mutual_information():
    probs = chain_probs(torch.zeros(3), 40)
    flat = probs.flatten(0, 1).double()
    mean = flat.mean(0)
    entropy = lambda p: -(p * p.log()).sum(-1)  # noqa: E731
    mi = entropy(mean) - entropy(flat).mean(0)
    torch.testing.assert_close(per_draw_mutual_information(probs).mean((0, 1)), mi)


def test_between_chain_share_of_mi():
    assert between_chain_mi_share(chain_probs(torch.zeros(4), 200)) < 0.05
    assert between_chain_mi_share(chain_probs(torch.tensor([0.0, 0.0, 4.0, 4.0]), 200)) > 0.3


def test_too_few_chains_or_draws_fail_clearly():
    with pytest.raises(ValueError, match="chains ≥ 2, draws ≥ 4"):
        function_space_diagnostics(chain_probs(torch.zeros(1), 10))
