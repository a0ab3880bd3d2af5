"""Last-layer Laplace approximation (Daxberger et al. 2021, "Laplace Redux") on the fixed MCD trunk.

Written directly in torch, not with laplace-torch: laplace-torch 0.3 requires torchvision, and
the PyPI torchvision wheel next to our CPU torch==2.13.0 breaks `import torchmetrics` (its C ops
do not register), so the package cannot be a dependency here. For the last layer the library's
default (GGN Hessian, full covariance, GLM predictive, prior precision by marginal likelihood)
is a few closed forms:
- a MAP head (Adam from the MCD head, N(0, σ²) prior); the three lower layers stay at the MAP;
- the last layer is linear in its weights W̃ = [W; b] [J, C] (J = inputs + 1), so the GGN is the
  exact Hessian of the NLL: H = Σ_n ψ_n ψ_nᵀ ⊗ (diag p_n − p_n p_nᵀ), ψ_n = [φ_n, 1];
- the prior precision λ maximises the Laplace evidence log p(D | θ*) − λ‖θ*‖²/2 + (P/2) log λ
  − ½ log det(H + λI) over a log grid (eigenvalues of H once, then every λ is cheap);
- the predictive of frame x is the GLM one: logits ~ N(W̃ᵀψ, (ψᵀ ⊗ I) Σ (ψ ⊗ I)), Σ = (H + λI)⁻¹.
  As the network is linear in the last layer, this is also the exact weight-space predictive.
Checked once against laplace-torch 0.3 (last_layer, full Hessian) on a toy network: Hessian and GLM logit
covariance agree to 1e-6 (its float32). Draws are drawn per frame from its C×C logit Gaussian (as VI's
local reparameterisation does): exact per frame, and n·C normals instead of n·P.
"""

from __future__ import annotations

import torch

from uqdrive.data.binning import SteeringBins
from uqdrive.models.heads import fixed_layer_features, flatten_mcd_head, head_nll, head_size, train_heads, unflatten
from uqdrive.models.pilotnet import Architecture
from uqdrive.models.posterior import Fitted, Posterior, check_draws
from uqdrive.models.training import TrainingData, curve_row, evaluate
from uqdrive.schema import Bool, Count, Positive, Seed, schema

PRIOR_GRID = torch.logspace(-4, 4, 161, dtype=torch.float64)  # candidate prior precisions λ
CHOLESKY_JITTER = 1e-6


@schema(frozen=True)
class LaplaceSettings:
    epochs: Seed  # Adam epochs from the MCD head to the MAP head (0: the MCD head is the MAP)
    batch_size: Count
    lr: Positive
    prior_sigma: Positive = 1.0  # prior of the MAP fit (and of the Laplace covariance unless optimise_prior)
    optimise_prior: Bool = True  # choose the last layer's prior precision by the Laplace evidence


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


def sample_glm_probs(mean: torch.Tensor, cov: torch.Tensor, n: int, generator: torch.Generator | None) -> torch.Tensor:
    """Softmax of n logit draws per frame from N(mean [B, C], cov [B, C, C]): [n, B, C]."""
    jitter = CHOLESKY_JITTER * torch.eye(cov.shape[-1], dtype=cov.dtype)
    scale = torch.linalg.cholesky(cov + jitter).float()  # factorised in double, applied in float
    z = torch.randn((mean.shape[0], n, mean.shape[1]), generator=generator)  # [B, n, C]
    logits = mean.float().unsqueeze(1) + torch.matmul(z, scale.transpose(1, 2))
    return torch.softmax(logits, -1).transpose(0, 1).contiguous()


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

    @torch.no_grad()
    def head_probs(self, features: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        mean, cov = glm_logits(self.last_layer_inputs(features), self.last_layer_weights(), self.covariance)
        return sample_glm_probs(mean, cov, check_draws(n), generator)

    @classmethod
    def fit(
        cls, settings: LaplaceSettings, data: TrainingData, generator: torch.Generator, progress: bool = False
    ) -> Fitted:
        base = data.base
        laplace = cls(base.arch, base.bins)
        laplace.trunk.load_state_dict(base.trunk.state_dict())
        laplace.trunk.requires_grad_(False)
        heads, _ = train_heads(
            flatten_mcd_head(base).unsqueeze(0),
            laplace.shapes,
            data.train_features,
            data.train.labels,
            data.val_features,
            data.val.labels,
            epochs=settings.epochs,
            batch_size=settings.batch_size,
            lr=settings.lr,
            prior_sigma=settings.prior_sigma,
            generator=generator,
            progress=progress,
            desc="laplace map",
        )
        laplace.head.copy_(heads[0])
        psi = laplace.last_layer_inputs(data.train_features)
        weights = laplace.last_layer_weights()
        with torch.no_grad():
            probs = torch.softmax(psi @ weights, -1)
            nll = float(head_nll(data.train_features, data.train.labels, heads, laplace.shapes)[0])
        hessian = last_layer_hessian(psi, probs)
        evidence = log_evidence(hessian, weights, nll, PRIOR_GRID)
        precision = float(PRIOR_GRID[evidence.argmax()]) if settings.optimise_prior else settings.prior_sigma**-2
        laplace.covariance.copy_(posterior_covariance(hessian, precision))
        scores = evaluate(laplace, data.val_features, data.val.labels, data.eval_samples, generator)
        curve = [curve_row(1, nll / len(data.train.labels), scores)]
        extra = {
            "prior_precision": precision,
            "log_evidence": float(evidence.max())
            if settings.optimise_prior
            else float(log_evidence(hessian, weights, nll, torch.tensor([precision], dtype=torch.float64))[0]),
            "last_layer_weights": int(weights.numel()),
        }
        extra["diagnostics"] = (
            f"last layer ({extra['last_layer_weights']} weights), prior precision "
            f"{precision:.3g}{' by evidence' if settings.optimise_prior else ''}"
        )
        return Fitted(laplace, curve, extra)
