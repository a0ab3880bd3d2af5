"""HMC posterior over the last `bayesian_layers` head layers on the fixed MCD trunk.

Fitting: a MAP head from the MCD head fixes the layers below the sampled ones (all four are
sampled when bayesian_layers = 4). Chains start dispersed, so chains that agree have found the
same distribution rather than inherited it, and the metric (mass matrix) is one of
- `laplace` (bayesian_layers = 1): the last layer's posterior is log-concave and close to the
  Gaussian of the Laplace approximation at the MAP, so HMC runs in the coordinates that whiten
  that Gaussian (dense mass = its precision); chains start at `start_scale`× overdispersed
  draws of it. Softmax weights are far from isotropic (a shift of all classes' weights leaves
  the likelihood unchanged), which an identity or diagonal metric mixes through very slowly;
- `diagonal`: each chain starts from its own He initialisation trained `start_epochs` towards
  its own MAP, with a diagonal mass adapted in warm-up (any number of layers).
Full-batch HMC with the step size adapted in warm-up. Convergence is judged in function space
(`uqdrive.models.diagnostics`); weight-space split-R̂ is kept as a secondary number.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import torch
from pydantic import Field

from uqdrive.models.diagnostics import RHAT_OK, between_chain_mi_share, function_space_diagnostics
from uqdrive.models.heads import (
    Shapes,
    StoredHeadPosterior,
    fixed_layer_features,
    flatten_mcd_head,
    he_init_heads,
    head_nll,
    head_size,
    train_heads,
    unflatten,
)
from uqdrive.models.laplace import last_layer_hessian, posterior_covariance, with_bias_input
from uqdrive.models.mcmc import HMCResult, LogProbGrad, hmc, split_rhat, whitened
from uqdrive.models.metrics import classification_metrics
from uqdrive.models.pilotnet import sampled_mlp_logits
from uqdrive.models.posterior import Fitted
from uqdrive.models.training import TrainingData, share_features
from uqdrive.schema import Bool, Count, Int, OpenUnit, Positive, Seed, Unit, invalid, schema


@schema(frozen=True)
class HMCSettings:
    chains: Annotated[Int, Field(ge=4)]  # R-hat compares chains from dispersed starts
    samples: Annotated[Int, Field(ge=4)]  # kept per chain (split R-hat needs 4)
    warmup: Seed  # iterations during which step size and mass adapt (discarded)
    thin: Count = 1
    bayesian_layers: Literal[1, 2, 3, 4] = 4  # the last k of the 4 head layers are sampled; those below: the MAP
    leapfrog_steps: Count = 10  # as in the paper
    step_size: Positive = 1e-3  # initial; adapted during warm-up
    target_accept: OpenUnit = 0.75
    metric: Literal["laplace", "diagonal"] = "laplace"  # laplace: dense, from the last-layer Laplace (1 layer)
    # diagonal mass adapted in warm-up, on top of the metric: true with metric=diagonal (with laplace the metric already
    # whitens; measured: adapting on top lowered bulk ESS and left all of warm-up's middle half to it)
    adapt_mass: Bool = False
    start_scale: Positive = 2.0  # metric=laplace: chains start at this many Laplace standard deviations' spread
    prior_sigma: Positive = 1.0
    map_epochs: Seed = 5  # minibatch Adam epochs from the MCD head to the MAP that fixes the lower layers
    start_epochs: Seed = 2  # minibatch Adam epochs of each chain from its own random start
    map_lr: Positive = 1e-3
    map_batch_size: Count = 64
    diagnostic_frames: Count = 200  # validation frames whose predictive R̂/ESS are computed
    rhat_target_share: Unit = 0.9  # of (frame, class) pairs with R̂ ≤ 1.1: the profile's convergence target

    def __post_init__(self) -> None:
        if self.metric == "laplace" and self.bayesian_layers != 1:
            raise invalid(
                "metric",
                self.metric,
                f"needs bayesian_layers=1, not {self.bayesian_layers} (laplace whitens the last layer only): "
                "use metric=diagonal",
            )


def head_log_posterior(
    features: torch.Tensor, labels: torch.Tensor, shapes: list[tuple[int, int]], prior_sigma: float
) -> LogProbGrad:
    """Unnormalised log posterior of heads (softmax likelihood of every frame + N(0, σ²) prior) and its gradient."""

    def log_prob_grad(theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        theta = theta.detach().requires_grad_(True)
        with torch.enable_grad():
            lp = -head_nll(features, labels, theta, shapes) - 0.5 * theta.square().sum(1) / prior_sigma**2
            (grad,) = torch.autograd.grad(lp.sum(), theta)
        return lp.detach(), grad

    return log_prob_grad


def settled_iteration(curve: list[dict]) -> int:
    """First recorded iteration from which the chains' mean training loss and validation NLL stay within 3 sd
    of their post-warm-up mean: when the run stopped drifting. Well below `warmup` means the warm-up is long
    enough; near or beyond it, the kept samples still carry the start."""
    kept = [row for row in curve if not row["warmup"]]
    settled = curve[0]["step"]
    for key in ("train_loss", "val_nll"):
        values = torch.tensor([r[key] for r in kept], dtype=torch.float64)
        centre, spread = float(values.mean()), 3 * float(values.std()) if len(values) > 1 else 0.0
        outside = [i for i, r in enumerate(curve) if abs(r[key] - centre) > spread]
        if outside and outside[-1] + 1 < len(curve):
            settled = max(settled, curve[outside[-1] + 1]["step"])
        elif outside:
            settled = max(settled, curve[-1]["step"])
    return settled


@dataclass(frozen=True)
class SampledLayers:
    """The head split for sampling: the MAP head (whose lower `fixed` layers stay put) and the inputs of the
    sampled layers on train and validation, computed once because every leapfrog step reuses them."""

    shapes: Shapes  # all head layers
    fixed: int
    head: torch.Tensor  # the MAP head, flat [D]
    train_phi: torch.Tensor
    val_phi: torch.Tensor
    train_labels: torch.Tensor
    val_labels: torch.Tensor

    @property
    def sampled_shapes(self) -> Shapes:
        return self.shapes[self.fixed :]

    @property
    def fixed_head(self) -> torch.Tensor:
        return self.head[: head_size(self.shapes[: self.fixed])]

    @property
    def sampled_head(self) -> torch.Tensor:
        return self.head[head_size(self.shapes[: self.fixed]) :]

    def log_posterior(self, prior_sigma: float) -> LogProbGrad:
        """The sampled layers' log posterior on the training inputs, in head-weight coordinates."""
        return head_log_posterior(self.train_phi, self.train_labels, self.sampled_shapes, prior_sigma)


@dataclass(frozen=True)
class ChainSpace:
    """Where the chains move: the log posterior in sampler coordinates u, the chains' starts in them, and the
    affine map u ↦ θ = centre + scale·u back to head weights (the identity when no metric whitens)."""

    log_prob_grad: LogProbGrad
    starts: torch.Tensor  # [chains, D_k]
    centre: torch.Tensor | None = None
    scale: torch.Tensor | None = None

    def to_theta(self, u: torch.Tensor) -> torch.Tensor:
        return u if self.scale is None else self.centre + u @ self.scale.T


def sampled_layers(
    settings: HMCSettings, data: TrainingData, generator: torch.Generator, progress: bool
) -> SampledLayers:
    """Train the MCD head towards its MAP when layers below the sampled ones are kept fixed (they must be a
    good fit, as no chain moves them); with the whole head sampled the MCD head is only the centre."""
    shapes = data.base.arch.head_shapes(data.base.num_classes)
    fixed = len(shapes) - settings.bayesian_layers
    train_labels, val_labels = data.train.labels, data.val.labels
    head = flatten_mcd_head(data.base)
    if fixed:
        head = train_heads(
            head.view(1, 1, -1),
            shapes,
            data.train_features.unsqueeze(0),
            train_labels,
            data.val_features.unsqueeze(0),
            val_labels,
            epochs=settings.map_epochs,
            batch_size=settings.map_batch_size,
            lr=settings.map_lr,
            prior_sigma=settings.prior_sigma,
            generators=[generator],
            progress=progress,
            desc="hmc map",
        )[0][0, 0]
    return SampledLayers(
        shapes,
        fixed,
        head,
        fixed_layer_features(data.train_features, head, shapes, fixed),
        fixed_layer_features(data.val_features, head, shapes, fixed),
        train_labels,
        val_labels,
    )


def laplace_space(settings: HMCSettings, layers: SampledLayers, generator: torch.Generator) -> ChainSpace:
    """Whiten by the last layer's Laplace Gaussian at the MAP (its Cholesky factor), so that identity mass in u is
    the dense Laplace precision in θ; chains start at `start_scale`× overdispersed draws of that Gaussian, so
    chains that agree have found the posterior rather than inherited a common start."""
    centre = layers.sampled_head  # the MAP's last layer, flat = W̃ [J, C] row-major
    psi = with_bias_input(layers.train_phi).double()
    weights = centre.double().view(psi.shape[1], -1)
    hessian = last_layer_hessian(psi, torch.softmax(psi @ weights, -1))
    scale = torch.linalg.cholesky(posterior_covariance(hessian, settings.prior_sigma**-2)).float()
    starts = settings.start_scale * torch.randn((settings.chains, len(centre)), generator=generator)
    return ChainSpace(whitened(layers.log_posterior(settings.prior_sigma), centre, scale), starts, centre, scale)


def dispersed_space(
    settings: HMCSettings, layers: SampledLayers, generator: torch.Generator, progress: bool
) -> ChainSpace:
    """Each chain starts from its own He initialisation trained `start_epochs` towards its own mode: dispersed,
    but past the first steep descent that a random head would spend warm-up on."""
    starts = train_heads(
        he_init_heads(settings.chains, layers.sampled_shapes, generator).unsqueeze(0),
        layers.sampled_shapes,
        layers.train_phi.unsqueeze(0),
        layers.train_labels,
        layers.val_phi.unsqueeze(0),
        layers.val_labels,
        epochs=settings.start_epochs,
        batch_size=settings.map_batch_size,
        lr=settings.map_lr,
        prior_sigma=settings.prior_sigma,
        generators=[generator],
        progress=progress,
        desc="hmc starts",
    )[0][0]
    return ChainSpace(layers.log_posterior(settings.prior_sigma), starts)


class CurveRecorder:
    """The learning curve as HMC's callback: about 100 rows over the run (and the last iteration), each with the
    chains' mean training loss per frame and the validation metrics of the chains' current mixture, so warm-up's
    drift and the settled iteration can be read off."""

    def __init__(self, settings: HMCSettings, layers: SampledLayers, space: ChainSpace) -> None:
        self.layers, self.space, self.warmup = layers, space, settings.warmup
        self.total = settings.warmup + settings.samples * settings.thin
        self.every = max(1, self.total // 100)
        self.rows: list[dict] = []

    def __call__(self, it: int, theta: torch.Tensor, lp: torch.Tensor, accept_prob: torch.Tensor) -> None:
        if (it + 1) % self.every and it + 1 != self.total:
            return
        layers = self.layers
        heads = unflatten(self.space.to_theta(theta), layers.sampled_shapes)
        probs = torch.softmax(sampled_mlp_logits(layers.val_phi, heads), -1).mean(0)
        scores = classification_metrics(probs, layers.val_labels)
        self.rows.append(
            {
                "step": it + 1,
                "train_loss": float(-lp.mean()) / len(layers.train_labels),
                "val_accuracy": scores["accuracy"],
                "val_nll": scores["nll"],
                "accept_prob": float(accept_prob.mean()),
                "warmup": int(it < self.warmup),
            }
        )


def run_chains(
    settings: HMCSettings, space: ChainSpace, recorder: CurveRecorder, generator: torch.Generator, progress: bool
) -> HMCResult:
    """Warm-up (step size, and diagonal mass if asked, adapt) and sampling, all chains as one batch."""
    return hmc(
        space.log_prob_grad,
        space.starts,
        num_samples=settings.samples,
        warmup=settings.warmup,
        thin=settings.thin,
        leapfrog_steps=settings.leapfrog_steps,
        step_size=settings.step_size,
        target_accept=settings.target_accept,
        adapt_mass=settings.adapt_mass,
        generator=generator,
        callback=recorder,
        progress=progress,
        desc="hmc",
    )


def chain_predictives(settings: HMCSettings, layers: SampledLayers, samples: torch.Tensor, chains: int) -> torch.Tensor:
    """Class probabilities [chains, kept, frames, C] of every kept sample on `diagnostic_frames` validation frames
    spread evenly over the split: what convergence is judged on, since weights are not identifiable."""
    labels = layers.val_labels
    frames = torch.linspace(0, len(labels) - 1, min(settings.diagnostic_frames, len(labels))).long()
    with torch.no_grad():
        probs = torch.softmax(sampled_mlp_logits(layers.val_phi[frames], unflatten(samples, layers.sampled_shapes)), -1)
    return probs.view(chains, len(samples) // chains, len(frames), -1)


def fit_metrics(
    settings: HMCSettings, result: HMCResult, samples: torch.Tensor, probs: torch.Tensor, curve: list[dict]
) -> dict[str, Any]:
    """The run's metrics for metrics/train: function-space R̂/ESS first (what the profile's target is on), then
    warm-up's length against when the run settled, acceptance, step size and weight-space R̂ (secondary)."""
    chains, kept = result.samples.shape[:2]
    fs = function_space_diagnostics(probs)
    weight_rhat = split_rhat(samples.view(chains, kept, -1))
    extra = {
        **fs,
        "settled_iteration": settled_iteration(curve),
        "warmup": settings.warmup,
        "fs_rhat_target_share": settings.rhat_target_share,
        "fs_rhat_target_met": int(fs["fs_rhat_share_ok"] >= settings.rhat_target_share),
        "between_chain_mi_share": between_chain_mi_share(probs),
        "chains": chains,
        "bayesian_weights": result.samples.shape[2],
        "accept_rate": float(result.accept_rate.mean()),
        "accept_rate_min_chain": float(result.accept_rate.min()),
        "step_size": float(result.step_size.mean()),
        "rhat_max": float(weight_rhat.max()),
        "rhat_median": float(weight_rhat.median()),
        "rhat_log_prob": float(split_rhat(result.log_prob)),
        "kept_samples": int(chains * kept),
    }
    extra["diagnostics"] = diagnostics_summary(settings, extra)
    return extra


def diagnostics_summary(settings: HMCSettings, extra: dict) -> str:
    """One sentence for the report: the run's shape, then whether it converged, in the order a reader checks."""
    return (
        f"{extra['chains']} chains × {extra['kept_samples'] // extra['chains']} samples ({settings.metric} metric) "
        f"over the last {settings.bayesian_layers} layer(s) "
        f"({extra['bayesian_weights']} weights); function-space R̂ ≤ {RHAT_OK} for "
        f"{100 * extra['fs_rhat_share_ok']:.0f}% of {extra['fs_pairs']} (frame, class) pairs "
        f"(target {100 * settings.rhat_target_share:.0f}%), median {extra['fs_rhat_median']:.3f}, "
        f"min bulk/tail ESS {extra['fs_ess_bulk_min']:.0f}/{extra['fs_ess_tail_min']:.0f}; MI R̂ max "
        f"{extra['mi_rhat_max']:.2f}, min ESS {extra['mi_ess_bulk_min']:.0f}; loss and predictive settled by iteration "
        f"{extra['settled_iteration']} of {settings.warmup} warm-up; acceptance {extra['accept_rate']:.2f}; "
        f"weight-space split-R̂ median {extra['rhat_median']:.2f} (secondary)"
    )


class HMCPosterior(StoredHeadPosterior):
    """Draws index the stored samples: without replacement when n ≤ S, with replacement when n > S."""

    method = "hmc"
    Settings = HMCSettings
    curve_unit = "iteration"

    def draw_index(self, n: int, generator: torch.Generator | None) -> torch.Tensor:
        stored = len(self.samples)
        if n > stored:
            return torch.randint(stored, (n,), generator=generator)
        return torch.randperm(stored, generator=generator)[:n]

    @classmethod
    def fit_replicates(
        cls,
        settings: HMCSettings,
        data: Sequence[TrainingData],
        generators: Sequence[torch.Generator],
        progress: bool = False,
    ) -> list[Fitted]:
        """Every replicate's trunk features at once (`share_features`), then each replicate's chains apart (`fit`).

        Not stacked: a replicate's chains already run as one batch on full-batch gradients over every frame, so
        stacking replicates would save only Python overhead per leapfrog step, at the price of a kernel that draws
        each replicate's momenta and accept/reject from its own generator and adapts, whitens and records each
        replicate apart. Measured at the tiny profile, ArviZ's per-pair function-space diagnostics were ~75% of an
        HMC fit, and they are per replicate either way."""
        share_features(data)
        return [cls.fit(settings, d, g, progress) for d, g in zip(data, generators, strict=True)]

    @classmethod
    def fit(
        cls, settings: HMCSettings, data: TrainingData, generator: torch.Generator, progress: bool = False
    ) -> Fitted:
        layers = sampled_layers(settings, data, generator, progress)
        if settings.metric == "laplace":
            space = laplace_space(settings, layers, generator)
        else:
            space = dispersed_space(settings, layers, generator, progress)
        recorder = CurveRecorder(settings, layers, space)
        result = run_chains(settings, space, recorder, generator, progress)
        samples = space.to_theta(result.samples.flatten(0, 1))  # [chains·kept, D_k], chain-major
        probs = chain_predictives(settings, layers, samples, chains=result.samples.shape[0])
        extra = fit_metrics(settings, result, samples, probs, recorder.rows)
        posterior = cls.from_heads(data.base, samples, layers.fixed_head, layers.fixed)
        return Fitted(posterior, recorder.rows, extra)
