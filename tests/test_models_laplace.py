"""Last-layer Laplace: the closed-form Hessian, the prior precision's choice (evidence, validation NLL), the GLM
predictive on a toy problem, and the fit's learning curve."""

import pytest
import torch
from test_models_hmc import head_problem
from torch.nn.functional import cross_entropy

from uqdrive.models.laplace import (
    PRIOR_GRID,
    VALIDATION_GRID,
    LaplacePosterior,
    LaplaceSettings,
    glm_logits,
    glm_softmax,
    last_layer_hessian,
    log_evidence,
    posterior_covariance,
    sample_glm_probs,
    validation_nll,
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


def test_validation_nll_is_the_nll_of_the_sampled_predictive_at_each_precision():
    """Against the direct path: Σ = (H + λI)⁻¹ by Cholesky, the GLM logit moments, the same standard normals."""
    x, y = separable_problem(90)
    x[:, 1] *= 3.0  # unequal input scales: the Hessian's eigenvalues spread
    psi = with_bias_input(x)
    w = map_weights(psi, y, precision=1.0)
    hessian = last_layer_hessian(psi, torch.softmax(psi @ w, -1))
    val_x, val_y = separable_problem(70, seed=1)
    val_psi = with_bias_input(val_x)
    precisions = torch.tensor([1e-3, 0.3, 10.0, 1e3], dtype=torch.float64)
    got = validation_nll(hessian, w, val_psi, val_y, precisions, 30, torch.Generator().manual_seed(4), chunk=16)
    normals = torch.randn((70, 30, 2), generator=torch.Generator().manual_seed(4))
    for precision, nll in zip(precisions, got):
        mean, cov = glm_logits(val_psi, w, posterior_covariance(hessian, float(precision)))
        probs = glm_softmax(mean, cov, normals).mean(1).double()
        expected = -probs[torch.arange(70), val_y].log().mean()
        torch.testing.assert_close(nll, expected, rtol=1e-6, atol=0)
    assert got[0] > got[-1]  # the nearly flat prior spreads the margin's draws: worse than a tight posterior here


@pytest.mark.parametrize("epochs", [0, 3])
def test_fit_curve_has_each_map_epoch_then_the_laplace_step(epochs):
    data = head_problem()
    settings = LaplaceSettings(epochs=epochs, batch_size=32, lr=1e-2)
    fitted = LaplacePosterior.fit(settings, data, torch.Generator().manual_seed(0))
    curve = fitted.curve
    assert [row["step"] for row in curve] == list(range(1, epochs + 2))
    assert [row["laplace"] for row in curve] == [0] * epochs + [1]
    assert all({"step", "train_loss", "val_accuracy", "val_nll"} <= set(row) for row in curve)
    posterior = fitted.posterior
    logits = posterior.last_layer_inputs(data.val_features) @ posterior.last_layer_weights()
    if epochs:  # the MAP rows score the MAP head alone: the last one is the head the Laplace step starts from
        map_accuracy = float((logits.argmax(1) == data.val.labels).double().mean())
        map_nll = float(cross_entropy(logits, data.val.labels))
        assert abs(curve[-2]["val_accuracy"] - map_accuracy) <= 1 / len(data.val.labels)
        assert abs(curve[-2]["val_nll"] - map_nll) < 0.01 * map_nll
    assert fitted.extra["prior_precision"] in VALIDATION_GRID.tolist()
    assert PRIOR_GRID[0] <= fitted.extra["evidence_prior_precision"] <= PRIOR_GRID[-1]


def test_each_prior_tuning_sets_the_covariance_it_reports():
    data = head_problem()
    chosen = {}
    for tuning in ("validation", "evidence", "fixed"):
        settings = LaplaceSettings(epochs=1, batch_size=32, lr=1e-2, prior_sigma=0.5, prior_tuning=tuning)
        fitted = LaplacePosterior.fit(settings, data, torch.Generator().manual_seed(0))
        posterior, extra = fitted.posterior, fitted.extra
        psi = posterior.last_layer_inputs(data.train_features)
        hessian = last_layer_hessian(psi, torch.softmax(psi @ posterior.last_layer_weights(), -1))
        torch.testing.assert_close(posterior.covariance, posterior_covariance(hessian, extra["prior_precision"]))
        chosen[tuning] = extra
    assert chosen["fixed"]["prior_precision"] == 4.0  # 1 / prior_sigma²
    assert chosen["evidence"]["prior_precision"] == chosen["evidence"]["evidence_prior_precision"]
    assert "by validation NLL" in chosen["validation"]["diagnostics"]
