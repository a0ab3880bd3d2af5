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

from typing import Annotated, Literal

import torch
from pydantic import Field

from uqdrive.models.diagnostics import RHAT_OK, between_chain_mi_share, function_space_diagnostics
from uqdrive.models.heads import (
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
from uqdrive.models.mcmc import LogProbGrad, hmc, split_rhat, whitened
from uqdrive.models.metrics import classification_metrics
from uqdrive.models.pilotnet import sampled_mlp_logits
from uqdrive.models.posterior import Fitted
from uqdrive.models.training import TrainingData
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
    def fit(
        cls, settings: HMCSettings, data: TrainingData, generator: torch.Generator, progress: bool = False
    ) -> Fitted:
        base = data.base
        shapes = base.arch.head_shapes(base.num_classes)
        fixed = len(shapes) - settings.bayesian_layers
        sampled_shapes = shapes[fixed:]
        train_labels, val_labels = data.train.labels, data.val.labels
        head = flatten_mcd_head(base)
        if fixed:
            head = train_heads(
                head.unsqueeze(0),
                shapes,
                data.train_features,
                train_labels,
                data.val_features,
                val_labels,
                epochs=settings.map_epochs,
                batch_size=settings.map_batch_size,
                lr=settings.map_lr,
                prior_sigma=settings.prior_sigma,
                generator=generator,
                progress=progress,
                desc="hmc map",
            )[0][0]
        train_phi = fixed_layer_features(data.train_features, head, shapes, fixed)
        val_phi = fixed_layer_features(data.val_features, head, shapes, fixed)
        log_prob_grad = head_log_posterior(train_phi, train_labels, sampled_shapes, settings.prior_sigma)
        if settings.metric == "laplace":
            centre = head[head_size(shapes[:fixed]) :]  # the MAP's last layer, flat = W̃ [J, C] row-major
            psi = with_bias_input(train_phi).double()
            weights = centre.double().view(psi.shape[1], -1)
            hessian = last_layer_hessian(psi, torch.softmax(psi @ weights, -1))
            scale = torch.linalg.cholesky(posterior_covariance(hessian, settings.prior_sigma**-2)).float()
            to_theta = lambda u: centre + u @ scale.T  # noqa: E731
            log_prob_grad = whitened(log_prob_grad, centre, scale)
            starts = settings.start_scale * torch.randn((settings.chains, len(centre)), generator=generator)
        else:
            to_theta = lambda u: u  # noqa: E731
            starts = train_heads(
                he_init_heads(settings.chains, sampled_shapes, generator),
                sampled_shapes,
                train_phi,
                train_labels,
                val_phi,
                val_labels,
                epochs=settings.start_epochs,
                batch_size=settings.map_batch_size,
                lr=settings.map_lr,
                prior_sigma=settings.prior_sigma,
                generator=generator,
                progress=progress,
                desc="hmc starts",
            )[0]
        n_train = len(train_labels)
        total = settings.warmup + settings.samples * settings.thin
        every = max(1, total // 100)
        curve: list[dict] = []

        def record(it: int, theta: torch.Tensor, lp: torch.Tensor, accept_prob: torch.Tensor) -> None:
            if (it + 1) % every and it + 1 != total:
                return
            probs = torch.softmax(sampled_mlp_logits(val_phi, unflatten(to_theta(theta), sampled_shapes)), -1).mean(0)
            scores = classification_metrics(probs, val_labels)
            curve.append(
                {
                    "step": it + 1,
                    "train_loss": float(-lp.mean()) / n_train,
                    "val_accuracy": scores["accuracy"],
                    "val_nll": scores["nll"],
                    "accept_prob": float(accept_prob.mean()),
                    "warmup": int(it < settings.warmup),
                }
            )

        result = hmc(
            log_prob_grad,
            starts,
            num_samples=settings.samples,
            warmup=settings.warmup,
            thin=settings.thin,
            leapfrog_steps=settings.leapfrog_steps,
            step_size=settings.step_size,
            target_accept=settings.target_accept,
            adapt_mass=settings.adapt_mass,
            generator=generator,
            callback=record,
            progress=progress,
            desc="hmc",
        )
        chains, kept = result.samples.shape[:2]
        samples = to_theta(result.samples.flatten(0, 1))  # [chains·kept, D_k], chain-major
        frames = torch.linspace(0, len(val_labels) - 1, min(settings.diagnostic_frames, len(val_labels))).long()
        with torch.no_grad():
            probs = torch.softmax(sampled_mlp_logits(val_phi[frames], unflatten(samples, sampled_shapes)), -1)
        probs = probs.view(chains, kept, len(frames), -1)
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
        extra["diagnostics"] = (
            f"{chains} chains × {kept} samples ({settings.metric} metric) "
            f"over the last {settings.bayesian_layers} layer(s) "
            f"({extra['bayesian_weights']} weights); function-space R̂ ≤ {RHAT_OK} for "
            f"{100 * fs['fs_rhat_share_ok']:.0f}% of {fs['fs_pairs']} (frame, class) pairs "
            f"(target {100 * settings.rhat_target_share:.0f}%), median {fs['fs_rhat_median']:.3f}, "
            f"min bulk/tail ESS {fs['fs_ess_bulk_min']:.0f}/{fs['fs_ess_tail_min']:.0f}; MI R̂ max "
            f"{fs['mi_rhat_max']:.2f}, min ESS {fs['mi_ess_bulk_min']:.0f}; loss and predictive settled by iteration "
            f"{extra['settled_iteration']} of {settings.warmup} warm-up; acceptance {extra['accept_rate']:.2f}; "
            f"weight-space split-R̂ median {extra['rhat_median']:.2f} (secondary)"
        )
        return Fitted(cls.from_heads(base, samples, head[: head_size(shapes[:fixed])], fixed), curve, extra)
