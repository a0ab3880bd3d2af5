"""Heads as flat weight vectors on the fixed trunk, and posteriors that store a set of them.

A head's weights live as one flat vector (layer by layer: W [in, out], then b), so HMC's generic
kernel can sample them, many heads train side by side as batch dimensions (replicates, and within
each its ensemble members or HMC chains' starts), and `head_probs` evaluates a set of stored heads
with one batched matmul per layer.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence

import torch
from tqdm import trange

from uqdrive.data.binning import SteeringBins
from uqdrive.models.pilotnet import Architecture, sampled_mlp_logits
from uqdrive.models.posterior import Posterior, check_draws, per_frame_linear
from uqdrive.models.stacking import adam, per_replicate, replicate_rows
from uqdrive.models.training import curve_row, evaluate

Shapes = list[tuple[int, int]]


def head_size(shapes: Shapes) -> int:
    return sum(i * o + o for i, o in shapes)


def unflatten(theta: torch.Tensor, shapes: Shapes) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Flat head weights [k, D] → [(W [k, in, out], b [k, out])] as views (no copy)."""
    layers, start = [], 0
    for i, o in shapes:
        w = theta[:, start : start + i * o].view(-1, i, o)
        start += i * o
        layers.append((w, theta[:, start : start + o]))
        start += o
    return layers


def flatten_mcd_head(mcd: Posterior) -> torch.Tensor:
    """An MCD head's weights (without dropout) as one flat vector [D]."""
    return torch.cat([t for layer in mcd.head for t in (layer.weight.T.flatten(), layer.bias)]).detach()


def fixed_layer_features(
    features: torch.Tensor, head: torch.Tensor, shapes: list[tuple[int, int]], fixed: int
) -> torch.Tensor:
    """Inputs [N, F_k] of the first sampled layer: features through the `fixed` lowest layers of `head` [D]."""
    h = features
    for w, b in unflatten(head.unsqueeze(0), shapes[:fixed]):
        h = torch.relu(h @ w[0] + b[0])
    return h


def he_init_heads(count: int, shapes: Shapes, generator: torch.Generator) -> torch.Tensor:
    """`count` independent He-uniform initialisations [count, D] (zero biases), as `init_weights` draws them."""
    parts = []
    for i, o in shapes:
        bound = (6.0 / i) ** 0.5
        parts += [(2 * torch.rand((count, i * o), generator=generator) - 1) * bound, torch.zeros(count, o)]
    return torch.cat(parts, 1)


def head_nll(features: torch.Tensor, labels: torch.Tensor, theta: torch.Tensor, shapes: Shapes) -> torch.Tensor:
    """Summed softmax negative log-likelihood [k] of each of k heads θ [k, D] on features [N, F] (or [k, N, F]),
    labels [N] (or [k, N]).

    The last layer's logits are laid out classes first [k, C, N], so its matmul's long side and the log-sum-exp's
    vector run along the frames: HMC's full-batch gradient (4 chains × 4,413 frames × 10 classes) took 9.4 ms with
    [k, N, C] logits and `cross_entropy` (whose softmax over 10 contiguous classes barely vectorises), 2.1 ms so.
    """
    *hidden, (weight, bias) = unflatten(theta, shapes)
    h = torch.relu(sampled_mlp_logits(features, hidden)) if hidden else features
    logits = torch.matmul(weight.transpose(1, 2), h.transpose(-1, -2)) + bias.unsqueeze(2)  # [k, C, N]
    top = logits.detach().amax(1, keepdim=True)
    log_total = (logits - top).exp().sum(1).log() + top.squeeze(1)
    return (log_total - logits.gather(1, labels.expand(len(theta), -1).unsqueeze(1)).squeeze(1)).sum(1)


def train_heads(
    theta: torch.Tensor,
    shapes: Shapes,
    features: torch.Tensor,
    labels: torch.Tensor,
    val_features: torch.Tensor,
    val_labels: torch.Tensor,
    *,
    epochs: int,
    batch_size: int,
    lr: float,
    prior_sigma: float,
    generators: Sequence[torch.Generator],
    progress: bool,
    desc: str,
    scored: Sequence[Posterior] | None = None,
    eval_samples: int = 1,
) -> tuple[torch.Tensor, list[list[dict]]]:
    """MAP training of R replicates' k heads θ [R, k, D] side by side (Adam; each head its own minibatch order),
    replicate r's on its features [R, N, F] (validation [R, M, F]), its orders from ``generators[r]``.

    Loss per frame: cross-entropy + ‖θ‖²/(2σ²N), the MAP of the same N(0, σ²) prior as VI and HMC.
    ``scored[r]`` (a posterior viewing replicate r's θ) is evaluated on validation after each epoch for its curve.
    Returns the heads [R, k, D] and the replicates' curves.
    """
    replicates, heads = theta.shape[:2]
    theta = theta.detach().clone().requires_grad_(True)
    optimizer = adam([theta], lr)
    n_train = len(labels)
    curves: list[list[dict]] = [[] for _ in range(replicates)]
    for epoch in trange(1, epochs + 1, desc=desc, unit="epoch", disable=not progress):
        order = per_replicate(  # [R, k, N]
            generators, lambda g: torch.stack([torch.randperm(n_train, generator=g) for _ in range(heads)])
        )
        totals = torch.zeros(replicates, dtype=torch.float64)
        for index in order.split(batch_size, dim=2):
            rows = replicate_rows(features, index).flatten(0, 1)  # [R·k, b, F]
            nll = head_nll(rows, labels[index].flatten(0, 1), theta.flatten(0, 1), shapes).view(replicates, heads)
            nll = nll / index.shape[2]
            loss = (nll + theta.square().sum(2) / (2 * prior_sigma**2 * n_train)).sum()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            totals += nll.detach().double().sum(1) * index.shape[2] / heads
        for r, posterior in enumerate(scored or []):
            with torch.no_grad():
                posterior.load_heads(theta[r].detach())
            scores = evaluate(posterior, val_features[r], val_labels, eval_samples, generators[r])
            curves[r].append(curve_row(epoch, float(totals[r]) / n_train, scores))
    return theta.detach(), curves


class StoredHeadPosterior(Posterior):
    """A posterior given by S stored heads (HMC samples, ensemble members); draws index them.

    The lowest `fixed_layers` head layers may be shared by every stored head (HMC over the last
    layers only): they are stored once and run once per frame batch, before the stored heads.
    """

    def __init__(self, arch: Architecture, bins: SteeringBins, num_samples: int, fixed_layers: int = 0) -> None:
        super().__init__(arch, bins)
        head_shapes = arch.head_shapes(bins.num_classes)
        if not 0 <= fixed_layers < len(head_shapes):
            raise ValueError(
                f"fixed_layers={fixed_layers} must leave at least one of the {len(head_shapes)} head layers to sample"
            )
        self.fixed_layers = fixed_layers
        self.fixed_shapes, self.shapes = head_shapes[:fixed_layers], head_shapes[fixed_layers:]
        self.register_buffer("fixed_head", torch.zeros(head_size(self.fixed_shapes)))
        self.register_buffer("samples", torch.zeros(num_samples, head_size(self.shapes)))

    @classmethod
    def from_heads(
        cls, base: Posterior, heads: torch.Tensor, fixed_head: torch.Tensor | None = None, fixed_layers: int = 0
    ) -> StoredHeadPosterior:
        """Keep the base model's trunk (frozen), the shared lowest layers (flat) and the heads [S, D] above them."""
        post = cls(base.arch, base.bins, len(heads), fixed_layers)
        post.trunk.load_state_dict(base.trunk.state_dict())
        post.trunk.requires_grad_(False)
        if fixed_layers:
            post.fixed_head.copy_(fixed_head)
        post.samples.copy_(heads)
        return post

    def load_heads(self, heads: torch.Tensor) -> None:
        self.samples.copy_(heads)

    def init_kwargs(self) -> dict:
        return {"num_samples": len(self.samples), "fixed_layers": self.fixed_layers}

    @abstractmethod
    def draw_index(self, n: int, generator: torch.Generator | None) -> torch.Tensor:
        """Which stored head each of n draws uses [n]."""

    def sampled_inputs(self, features: torch.Tensor) -> torch.Tensor:
        return fixed_layer_features(features, self.fixed_head, self.fixed_shapes, self.fixed_layers)

    @torch.no_grad()
    def head_probs(self, features: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """When n ≥ S every stored head is evaluated once and the outputs indexed (cheaper than copying n heads)."""
        index = self.draw_index(check_draws(n), generator)
        inputs = self.sampled_inputs(features)
        if n >= len(self.samples):
            return torch.softmax(sampled_mlp_logits(inputs, unflatten(self.samples, self.shapes)), -1)[index]
        return torch.softmax(sampled_mlp_logits(inputs, unflatten(self.samples[index], self.shapes)), -1)

    @torch.no_grad()
    def head_probs_each(self, features: torch.Tensor, n: int, generators: Sequence[torch.Generator]) -> torch.Tensor:
        """`head_probs` of each frame alone, [K, n, C]: the shared layers one same-shaped GEMM per frame, then every
        frame's n gathered heads as n GEMMs of one row each. With n ≥ S, frame by frame (a gathered copy of S heads
        per frame would cost more than it saves)."""
        n = check_draws(n)
        if n >= len(self.samples):
            return super().head_probs_each(features, n, generators)
        h = features.unsqueeze(1)  # [K, 1, F]
        for w, b in unflatten(self.fixed_head.unsqueeze(0), self.fixed_shapes):
            h = torch.relu(per_frame_linear(h, w[0], b[0]))
        index = torch.cat([self.draw_index(n, g) for g in generators])  # [K·n]: frame k's draws, its generator's
        logits = sampled_mlp_logits(h.repeat_interleave(n, 0), unflatten(self.samples[index], self.shapes))
        return torch.softmax(logits.view(len(generators), n, -1), -1)

    @torch.no_grad()
    def stored_probs(self, features: torch.Tensor) -> torch.Tensor:
        """Probabilities [S, B, C] of every stored head, in storage order (diagnostics compare them by chain)."""
        return torch.softmax(
            sampled_mlp_logits(self.sampled_inputs(features), unflatten(self.samples, self.shapes)), -1
        )
