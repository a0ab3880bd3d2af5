"""Last-layer Laplace: the closed-form Hessian, the evidence-chosen prior and the GLM predictive on a toy problem."""

import torch
from torch.nn.functional import cross_entropy

from uqdrive.models.laplace import (
    PRIOR_GRID,
    glm_logits,
    last_layer_hessian,
    log_evidence,
    posterior_covariance,
    sample_glm_probs,
    with_bias_input,
)


def separable_problem(n: int = 200, seed: int = 0):
    """2-D points, class 1 iff x0 > 0, with a margin of 0.5 around the boundary x0 = 0."""
    g = torch.Generator().manual_seed(seed)
    x = torch.randn((n, 2), generator=g, dtype=torch.float64)
    x[:, 0] += 0.5 * torch.sign(x[:, 0])
    return x, (x[:, 0] > 0).long()


def map_weights(psi: torch.Tensor, labels: torch.Tensor, precision: float) -> torch.Tensor:
    """MAP of softmax regression W̃ [J, 2] under N(0, 1/precision) by L-BFGS."""
    w = torch.zeros(psi.shape[1], 2, dtype=torch.float64, requires_grad=True)
    optimizer = torch.optim.LBFGS([w], max_iter=200, line_search_fn="strong_wolfe")

    def closure():
        optimizer.zero_grad()
        loss = cross_entropy(psi @ w, labels, reduction="sum") + 0.5 * precision * w.square().sum()
        loss.backward()
        return loss

    optimizer.step(closure)
    return w.detach()


def test_hessian_is_the_exact_hessian_of_the_last_layer_nll():
    x, y = separable_problem(30)
    psi = with_bias_input(x)
    w = 0.3 * torch.randn((3, 2), generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    exact = torch.autograd.functional.hessian(
        lambda v: cross_entropy(psi @ v.view(3, 2), y, reduction="sum"), w.flatten()
    )
    torch.testing.assert_close(last_layer_hessian(psi, torch.softmax(psi @ w, -1), chunk=7), exact)


def test_predictive_is_confident_far_from_the_boundary_and_uncertain_near_it():
    x, y = separable_problem()
    psi = with_bias_input(x)
    w = map_weights(psi, y, precision=1.0)
    probs = torch.softmax(psi @ w, -1)
    hessian = last_layer_hessian(psi, probs)
    nll = float(cross_entropy(psi @ w, y, reduction="sum"))
    evidence = log_evidence(hessian, w, nll, PRIOR_GRID)
    precision = float(PRIOR_GRID[evidence.argmax()])
    assert PRIOR_GRID[0] < precision < PRIOR_GRID[-1]  # an interior optimum, not the grid's edge
    cov = posterior_covariance(hessian, precision)
    queries = torch.tensor([[-4.0, 0.0], [4.0, 0.0], [0.0, 0.0], [0.0, 2.0]], dtype=torch.float64)
    mean, logit_cov = glm_logits(with_bias_input(queries), w, cov)
    draws = sample_glm_probs(mean, logit_cov, 4000, torch.Generator().manual_seed(0))  # [n, 4, 2]
    predictive = draws.mean(0)
    assert predictive[0, 0] > 0.97 and predictive[1, 1] > 0.97  # far on either side: confident and right
    assert abs(float(predictive[2, 0]) - 0.5) < 0.15 and abs(float(predictive[3, 0]) - 0.5) < 0.15  # on it: unsure
    spread = draws[..., 1].std(0)
    assert spread[2] > 5 * spread[0] and spread[3] > 5 * spread[1]  # draws disagree on the boundary, not far off


def test_glm_draws_have_the_predicted_logit_moments():
    mean = torch.tensor([[1.0, -1.0, 0.0]], dtype=torch.float64)
    a = torch.tensor([[[1.0, 0.3, 0.0], [0.3, 0.5, 0.1], [0.0, 0.1, 0.2]]], dtype=torch.float64)
    probs = sample_glm_probs(mean, a, 20000, torch.Generator().manual_seed(0))
    logits = probs.double().log()
    centred = logits - logits[..., :1]  # softmax loses the common shift: compare differences to class 0
    expected = mean - mean[:, :1]
    torch.testing.assert_close(centred.mean(0), expected, atol=0.03, rtol=0)
    d = torch.tensor([[-1.0, 1.0, 0.0]], dtype=torch.float64)
    var = float(d @ a[0] @ d.T)
    assert abs(float(centred[:, 0, 1].var()) - var) < 0.05 * var
