"""HMC posterior over the four head layers: a stored set of weight samples on the MCD trunk.

The head's weights live as one flat vector per sample (layer by layer: W [in, out], then b),
so the generic kernel in `uqdrive.models.mcmc` can sample them, and `head_probs` evaluates
many stored samples with one batched matmul per layer.
"""

from __future__ import annotations

import torch
from torch.nn.functional import cross_entropy

from uqdrive.data.binning import SteeringBins
from uqdrive.models.mcd import MCDPosterior
from uqdrive.models.mcmc import LogProbGrad
from uqdrive.models.pilotnet import Architecture, sampled_mlp_logits
from uqdrive.models.posterior import Posterior, check_draws


def head_size(shapes: list[tuple[int, int]]) -> int:
    return sum(i * o + o for i, o in shapes)


def unflatten(theta: torch.Tensor, shapes: list[tuple[int, int]]) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Flat head weights [k, D] → [(W [k, in, out], b [k, out])] as views (no copy)."""
    layers, start = [], 0
    for i, o in shapes:
        w = theta[:, start:start + i * o].view(-1, i, o)
        start += i * o
        layers.append((w, theta[:, start:start + o]))
        start += o
    return layers


def flatten_mcd_head(mcd: MCDPosterior) -> torch.Tensor:
    """The MCD head's weights as one flat vector [D] (the chains' starting point)."""
    return torch.cat([t for layer in mcd.head for t in (layer.weight.T.flatten(), layer.bias)]).detach()


def head_log_posterior(features: torch.Tensor, labels: torch.Tensor, shapes: list[tuple[int, int]],
                       prior_sigma: float) -> LogProbGrad:
    """Unnormalised log posterior of the head (softmax likelihood of every frame + N(0, σ²) prior) and its gradient."""
    n = len(labels)

    def log_prob_grad(theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        theta = theta.detach().requires_grad_(True)
        with torch.enable_grad():
            logits = sampled_mlp_logits(features, unflatten(theta, shapes))  # [chains, N, C]
            nll = cross_entropy(logits.flatten(0, 1), labels.repeat(len(theta)), reduction="none")
            lp = -nll.view(len(theta), n).sum(1) - 0.5 * theta.square().sum(1) / prior_sigma**2
            (grad,) = torch.autograd.grad(lp.sum(), theta)
        return lp.detach(), grad

    return log_prob_grad


class HMCPosterior(Posterior):
    method = "hmc"

    def __init__(self, arch: Architecture, bins: SteeringBins, num_samples: int) -> None:
        super().__init__(arch, bins)
        self.shapes = arch.head_shapes(bins.num_classes)
        self.register_buffer("samples", torch.zeros(num_samples, head_size(self.shapes)))

    @classmethod
    def from_samples(cls, mcd: MCDPosterior, samples: torch.Tensor) -> HMCPosterior:
        """Keep the MCD trunk (frozen) and the flat head samples [S, D] of all chains."""
        hmc = cls(mcd.arch, mcd.bins, len(samples))
        hmc.trunk.load_state_dict(mcd.trunk.state_dict())
        hmc.trunk.requires_grad_(False)
        hmc.samples.copy_(samples)
        return hmc

    def init_kwargs(self) -> dict:
        return {"num_samples": len(self.samples)}

    @torch.no_grad()
    def head_probs(self, features: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """n stored samples, drawn without replacement when n ≤ S and with replacement when n > S.

        When n ≥ S every stored sample is evaluated once and the outputs are indexed, which is
        cheaper than copying n weight vectors.
        """
        stored = len(self.samples)
        n = check_draws(n)
        if n > stored:
            index = torch.randint(stored, (n,), generator=generator)
        else:
            index = torch.randperm(stored, generator=generator)[:n]
        if n >= stored:
            return torch.softmax(sampled_mlp_logits(features, unflatten(self.samples, self.shapes)), -1)[index]
        return torch.softmax(sampled_mlp_logits(features, unflatten(self.samples[index], self.shapes)), -1)
