"""Last-layer Laplace approximation (Daxberger et al. 2021, "Laplace Redux") on the fixed MCD trunk.

Written directly in torch, not with laplace-torch: laplace-torch 0.3 requires torchvision, and
the PyPI torchvision wheel next to our CPU torch==2.13.0 breaks `import torchmetrics` (its C ops
do not register), so the package cannot be a dependency here. For the last layer the library's
set-up (GGN Hessian, full covariance, GLM predictive) is a few closed forms:
- a MAP head (Adam from the MCD head, N(0, σ²) prior); the three lower layers stay at the MAP;
- the last layer is linear in its weights W̃ = [W; b] [J, C] (J = inputs + 1), so the GGN is the
  exact Hessian of the NLL: H = Σ_n ψ_n ψ_nᵀ ⊗ (diag p_n − p_n p_nᵀ), ψ_n = [φ_n, 1];
- the predictive of frame x is the GLM one: logits ~ N(W̃ᵀψ, (ψᵀ ⊗ I) Σ (ψ ⊗ I)), Σ = (H + λI)⁻¹.
  As the network is linear in the last layer, this is also the exact weight-space predictive;
- the prior precision λ is, by default, the one on a log grid whose sampled predictive has the lowest
  validation NLL (laplace-torch's `optimize_prior_precision(method="gridsearch", val_loader=…)`, with
  `link_approx="mc"`: the draws are what the controller uses). The library's other choice, the Laplace
  evidence log p(D | θ*) − λ‖θ*‖²/2 + (P/2) log λ − ½ log det(H + λI) (`method="marglik"`), stays
  selectable and is always reported. Measured on the synthetic test road, whose MAP head is right on every
  frame: the GGN of a confident MAP is nearly zero (p(1 − p) ≈ 0 on every frame), so the evidence's λ ≈ 1.4
  leaves the prior's spread in almost every direction, logit standard deviations of 9–17 against a logit
  spread of ~25, and the sampled predictive puts its mass on classes never seen in training (validation
  accuracy 0.75 against the MAP's 1.0, NLL 1.97 against 0.05); the validation choice keeps the MAP's
  accuracy there. On the quick profile's data (seed 0) the two choices are closer: offline λ 39.8 against
  the evidence's 3.55, and tuned on one contiguous half of the validation frames, scored on the other, NLL
  0.242 → 0.174 and 0.287 → 0.223 at equal accuracy; avoid λ 6.3 against 3.55, about even (NLL 0.339 →
  0.355 and 0.218 → 0.214). The train stage's validation metrics are not held out for λ (one number chosen
  among 41); the evaluate stage's frames are.
Checked once against laplace-torch 0.3 (last_layer, full Hessian) on a toy network: Hessian and GLM logit
covariance agree to 1e-6 (its float32). Draws are drawn per frame from its C×C logit Gaussian (as VI's
local reparameterisation does): exact per frame, and n·C normals instead of n·P.

The learning curve has one row per MAP epoch (the MAP head alone: a Laplace posterior of zero covariance)
and a last row for the Laplace posterior (`laplace` = 1), so the panel shows the MAP converging and what
the covariance then does to the validation metrics.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import torch

from uqdrive.data.binning import SteeringBins
from uqdrive.models.heads import fixed_layer_features, flatten_mcd_head, head_nll, head_size, train_heads, unflatten
from uqdrive.models.metrics import PROB_FLOOR
from uqdrive.models.pilotnet import Architecture
from uqdrive.models.posterior import Fitted, Posterior, check_draws
from uqdrive.models.training import TrainingData, curve_row, evaluate, share_features, shared_frames
from uqdrive.schema import Count, Positive, Seed, schema

PRIOR_GRID = torch.logspace(-4, 4, 161, dtype=torch.float64)  # candidate prior precisions λ (laplace-torch's range)
VALIDATION_GRID = PRIOR_GRID[::4]  # 0.2 decades apart: each candidate samples the validation predictive once
CHOLESKY_JITTER = 1e-6


@schema(frozen=True)
class LaplaceSettings:
    epochs: Seed  # Adam epochs from the MCD head to the MAP head (0: the MCD head is the MAP)
    batch_size: Count
    lr: Positive
    prior_sigma: Positive = 1.0  # prior of the MAP fit (and of the Laplace covariance with prior_tuning=fixed)
    # the last layer's prior precision λ: validation = lowest validation NLL of the sampled predictive over a grid;
    # evidence = the Laplace evidence's maximum; fixed = 1/prior_sigma²
    prior_tuning: Literal["validation", "evidence", "fixed"] = "validation"


def with_bias_input(phi: torch.Tensor) -> torch.Tensor:
    """ψ = [φ, 1]: the last layer's inputs with a constant for its bias [N, J]."""
    return torch.cat([phi, torch.ones(len(phi), 1, dtype=phi.dtype)], 1)


def last_layer_hessian(psi: torch.Tensor, probs: torch.Tensor, chunk: int = 1024) -> torch.Tensor:
    """Σ_n ψ_n ψ_nᵀ ⊗ (diag p_n − p_n p_nᵀ) as [J·C, J·C], index j·C + c (W̃ [J, C] flattened row-major)."""
    psi, probs = psi.double(), probs.double()
    j, c = psi.shape[1], probs.shape[1]
    hessian = torch.zeros(j, c, j, c, dtype=torch.float64)
    for psi_part, p in zip(psi.split(chunk), probs.split(chunk)):
        curvature = torch.diag_embed(p) - p.unsqueeze(2) * p.unsqueeze(1)  # [n, C, C]
        hessian += torch.einsum("nj,nk,ncd->jckd", psi_part, psi_part, curvature)
    return hessian.reshape(j * c, j * c)


def log_evidence(hessian: torch.Tensor, weights: torch.Tensor, nll: float, precisions: torch.Tensor) -> torch.Tensor:
    """Laplace log evidence (up to a constant) at each prior precision λ, θ* and H held fixed."""
    eigenvalues = torch.linalg.eigvalsh(hessian.double()).clamp_min(0.0)
    size, squares = len(eigenvalues), float(weights.double().square().sum())
    return (
        -nll
        - 0.5 * precisions * squares
        + 0.5 * size * precisions.log()
        - 0.5 * (eigenvalues.unsqueeze(0) + precisions.unsqueeze(1)).log().sum(1)
    )


def posterior_covariance(hessian: torch.Tensor, precision: float) -> torch.Tensor:
    eye = torch.eye(len(hessian), dtype=torch.float64)
    return torch.cholesky_inverse(torch.linalg.cholesky(hessian.double() + precision * eye))


def glm_logits(psi: torch.Tensor, weights: torch.Tensor, covariance: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean [B, C] and covariance [B, C, C] of the logits under W̃ ~ N(weights [J, C], covariance [J·C, J·C])."""
    j, c = weights.shape
    mean = psi @ weights
    left = (psi @ covariance.reshape(j, c * j * c)).view(-1, c, j, c)  # Σ_j ψ_j Σ[(j,c),(k,d)]: one matmul
    cov = torch.matmul(left.transpose(2, 3), psi[:, None, :, None]).squeeze(-1)  # then Σ_k ·ψ_k: [B, C, C]
    return mean, cov


def glm_softmax(mean: torch.Tensor, cov: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """Softmax of the logits mean + L·z per frame for given standard normals z [B, n, C], L the Cholesky factor of
    cov [B, C, C] (factorised in cov's dtype, applied in the normals'): [B, n, C]."""
    jitter = CHOLESKY_JITTER * torch.eye(cov.shape[-1], dtype=cov.dtype)
    scale = torch.linalg.cholesky(cov + jitter).to(normals.dtype)
    return torch.softmax(mean.to(normals.dtype).unsqueeze(1) + torch.matmul(normals, scale.transpose(-2, -1)), -1)


def sample_glm_probs(mean: torch.Tensor, cov: torch.Tensor, n: int, generator: torch.Generator | None) -> torch.Tensor:
    """Softmax of n logit draws per frame from N(mean [B, C], cov [B, C, C]): [n, B, C]."""
    normals = torch.randn((mean.shape[0], n, mean.shape[1]), generator=generator)  # [B, n, C], float
    return glm_softmax(mean, cov, normals).transpose(0, 1).contiguous()


def validation_nll(
    hessian: torch.Tensor,
    weights: torch.Tensor,
    psi: torch.Tensor,
    labels: torch.Tensor,
    precisions: torch.Tensor,
    draws: int,
    generator: torch.Generator,
    chunk: int = 256,
) -> torch.Tensor:
    """Mean NLL [G] of the sampled GLM predictive (n = draws) on frames ψ [B, J] at each prior precision λ [G].

    Every λ reuses the same standard normals (common random numbers), so the NLL's differences between λ are
    not Monte Carlo noise. With H = QΛQᵀ once, a frame's logit covariance at λ is the Gram matrix of its Jacobian
    (ψᵀ ⊗ I)Q scaled by (Λ + λ)^(-1/2): no P×P inverse per λ.
    """
    eigenvalues, eigenvectors = torch.linalg.eigh(hessian.double())
    j, c = weights.shape
    basis = eigenvectors.view(j, c, -1)  # rows indexed j·C + c, as the Hessian's
    scales = (eigenvalues.clamp_min(0.0).unsqueeze(0) + precisions.double().unsqueeze(1)).rsqrt()  # [G, P]
    normals = torch.randn((len(psi), draws, c), generator=generator)
    total = torch.zeros(len(precisions), dtype=torch.float64)
    for psi_part, normals_part, labels_part in zip(psi.split(chunk), normals.split(chunk), labels.split(chunk)):
        mean = psi_part @ weights
        jacobian = torch.einsum("bj,jcp->bcp", psi_part, basis)  # [b, C, P]
        for i, scale in enumerate(scales):
            scaled = jacobian * scale
            probs = glm_softmax(mean, scaled @ scaled.transpose(1, 2), normals_part).mean(1).double()
            total[i] -= probs.gather(1, labels_part.unsqueeze(1)).clamp_min(PROB_FLOOR).log().sum()
    return total / len(psi)


class LaplacePosterior(Posterior):
    method = "laplace"
    Settings = LaplaceSettings

    def __init__(self, arch: Architecture, bins: SteeringBins) -> None:
        super().__init__(arch, bins)
        self.shapes = arch.head_shapes(bins.num_classes)
        inputs, classes = self.shapes[-1]
        self.register_buffer("head", torch.zeros(head_size(self.shapes)))  # the MAP head, flat
        self.register_buffer("covariance", torch.eye((inputs + 1) * classes, dtype=torch.float64))

    def last_layer_weights(self) -> torch.Tensor:
        """W̃ = [W; b] [J, C] of the MAP head."""
        w, b = unflatten(self.head.unsqueeze(0), self.shapes)[-1]
        return torch.cat([w[0], b]).double()

    def last_layer_inputs(self, features: torch.Tensor) -> torch.Tensor:
        return with_bias_input(fixed_layer_features(features, self.head, self.shapes, len(self.shapes) - 1)).double()

    def load_heads(self, heads: torch.Tensor) -> None:
        """The MAP head alone (heads [1, D], zero covariance): how `train_heads` scores each epoch of the MAP fit."""
        self.head.copy_(heads[0])
        self.covariance.zero_()

    @torch.no_grad()
    def head_probs(self, features: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        mean, cov = glm_logits(self.last_layer_inputs(features), self.last_layer_weights(), self.covariance)
        return sample_glm_probs(mean, cov, check_draws(n), generator)

    def choose_prior_precision(
        self,
        settings: LaplaceSettings,
        hessian: torch.Tensor,
        evidence: torch.Tensor,
        data: TrainingData,
        generator: torch.Generator,
    ) -> float:
        """λ as `prior_tuning` asks, for the MAP head held now; `evidence` is the log evidence over PRIOR_GRID."""
        if settings.prior_tuning == "evidence":
            return float(PRIOR_GRID[evidence.argmax()])
        if settings.prior_tuning == "fixed":
            return settings.prior_sigma**-2
        val_psi = self.last_layer_inputs(data.val_features)
        nll = validation_nll(
            hessian, self.last_layer_weights(), val_psi, data.val.labels, VALIDATION_GRID, data.eval_samples, generator
        )
        return float(VALIDATION_GRID[nll.argmin()])

    @classmethod
    def fit(
        cls, settings: LaplaceSettings, data: TrainingData, generator: torch.Generator, progress: bool = False
    ) -> Fitted:
        return cls.fit_replicates(settings, [data], [generator], progress)[0]

    @classmethod
    def fit_replicates(
        cls,
        settings: LaplaceSettings,
        data: Sequence[TrainingData],
        generators: Sequence[torch.Generator],
        progress: bool = False,
    ) -> list[Fitted]:
        """Every replicate's MAP head trained side by side (`train_heads`), then each its own Laplace step."""
        train, val = shared_frames(data)
        features, val_features = share_features(data)
        laplaces = []
        for d in data:
            laplace = cls(d.base.arch, d.base.bins)
            laplace.trunk.load_state_dict(d.base.trunk.state_dict())
            laplaces.append(laplace.requires_grad_(False))
        heads, map_curves = train_heads(
            torch.stack([flatten_mcd_head(d.base).unsqueeze(0) for d in data]),
            laplaces[0].shapes,
            features,
            train.labels,
            val_features,
            val.labels,
            epochs=settings.epochs,
            batch_size=settings.batch_size,
            lr=settings.lr,
            prior_sigma=settings.prior_sigma,
            generators=generators,
            progress=progress,
            desc="laplace map",
            scored=laplaces,
            eval_samples=data[0].eval_samples,
        )
        return [
            laplace.fit_covariance(settings, map_head, map_curve, d, g)
            for laplace, map_head, map_curve, d, g in zip(laplaces, heads, map_curves, data, generators)
        ]

    def fit_covariance(
        self,
        settings: LaplaceSettings,
        heads: torch.Tensor,
        map_curve: list[dict],
        data: TrainingData,
        generator: torch.Generator,
    ) -> Fitted:
        """The Laplace step on the MAP head heads [1, D]: GGN of the last layer, prior precision, covariance."""
        self.load_heads(heads)
        psi = self.last_layer_inputs(data.train_features)
        weights = self.last_layer_weights()
        with torch.no_grad():
            nll = float(head_nll(data.train_features, data.train.labels, heads, self.shapes)[0])
        hessian = last_layer_hessian(psi, torch.softmax(psi @ weights, -1))
        evidence = log_evidence(hessian, weights, nll, PRIOR_GRID)
        precision = self.choose_prior_precision(settings, hessian, evidence, data, generator)
        self.covariance.copy_(posterior_covariance(hessian, precision))
        scores = evaluate(self, data.val_features, data.val.labels, data.eval_samples, generator)
        curve = [{**row, "laplace": 0} for row in map_curve]
        curve.append(curve_row(settings.epochs + 1, nll / len(data.train.labels), scores, laplace=1))
        return Fitted(self, curve, laplace_metrics(settings, hessian, weights, nll, precision, evidence))


def laplace_metrics(
    settings: LaplaceSettings,
    hessian: torch.Tensor,
    weights: torch.Tensor,
    nll: float,
    precision: float,
    evidence: torch.Tensor,
) -> dict:
    """The chosen λ with its evidence, and the evidence's own choice beside it: how far the two disagree is
    how much the validation frames overrule the training frames' curvature."""
    at_choice = log_evidence(hessian, weights, nll, torch.tensor([precision], dtype=torch.float64))[0]
    extra = {
        "prior_precision": precision,
        "log_evidence": float(at_choice),
        "evidence_prior_precision": float(PRIOR_GRID[evidence.argmax()]),
        "last_layer_weights": int(weights.numel()),
    }
    how = {"validation": "by validation NLL", "evidence": "by evidence", "fixed": "fixed (1/prior_sigma²)"}
    extra["diagnostics"] = (
        f"last layer ({extra['last_layer_weights']} weights), prior precision {precision:.3g} "
        f"{how[settings.prior_tuning]} (the evidence's choice: {extra['evidence_prior_precision']:.3g})"
    )
    return extra
