"""MC dropout posterior: PilotNet with concrete dropout on the inputs of the last three head layers.

As in the paper, the first head layer (the "fourth" FC layer counted from the output) stays
plain; dropout rates are learned (concrete dropout) rather than tuned by grid search.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn
from torch.nn.functional import cross_entropy
from tqdm import trange

from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import FrameSet, to_inputs
from uqdrive.models.concrete_dropout import ConcreteDropout, dropout_regularizer, relaxed_dropout
from uqdrive.models.pilotnet import INPUT_SHAPE, Architecture, init_weights
from uqdrive.models.posterior import Fitted, Posterior, check_draws, per_frame_linear
from uqdrive.models.stacking import (
    adam,
    epoch_batches,
    per_replicate,
    stack_parameters,
    stacked_features,
    stacked_linear,
    stacked_trunk,
    unstack_into,
)
from uqdrive.models.training import TrainingData, curve_row, evaluate, shared_frames
from uqdrive.schema import Count, NonNegative, OpenUnit, Positive, schema


@schema(frozen=True)
class MCDSettings:
    epochs: Count
    batch_size: Count
    lr: Positive
    init_p: OpenUnit = 0.1  # initial dropout rate of each of the three layers (learned from there)
    temperature: Positive = 0.1  # of the concrete relaxation
    lengthscale: NonNegative = 1e-4  # prior length scale l of concrete dropout's weight term l²/N


class MCDPosterior(Posterior):
    method = "mcd"
    Settings = MCDSettings

    def __init__(self, arch: Architecture, bins: SteeringBins, init_p: float = 0.1, temperature: float = 0.1) -> None:
        super().__init__(arch, bins)
        shapes = arch.head_shapes(bins.num_classes)
        self.head = nn.ModuleList(nn.Linear(i, o) for i, o in shapes)
        self.dropout = nn.ModuleList(ConcreteDropout(i, init_p, temperature) for i, _ in shapes[1:])

    def init_kwargs(self) -> dict:
        return {"temperature": self.dropout[0].temperature}

    def dropout_rates(self) -> list[float]:
        return [d.p.item() for d in self.dropout]

    @torch.no_grad()
    def head_probs(self, features: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        n = check_draws(n)
        first, *layers = self.head  # (slicing a ModuleList builds a new one: a tenth of a closed-loop head call)
        h = torch.relu(first(features))  # no dropout before it: computed once, not n times
        for k, (drop, layer) in enumerate(zip(self.dropout, layers)):
            h = torch.matmul(h * drop.sample_masks(n, generator), layer.weight.T) + layer.bias
            if k < len(self.dropout) - 1:
                h = torch.relu(h)
        return torch.softmax(h, dim=-1)

    @torch.no_grad()
    def head_probs_each(self, features: torch.Tensor, n: int, generators: Sequence[torch.Generator]) -> torch.Tensor:
        """`head_probs` of each frame alone, every layer one same-shaped GEMM per frame: [K, n, C]."""
        n = check_draws(n)
        first, *layers = self.head
        h = torch.relu(per_frame_linear(features.unsqueeze(1), first.weight.T, first.bias))  # [K, 1, width]
        for k, (drop, layer) in enumerate(zip(self.dropout, layers)):
            masks = torch.stack([drop.sample_masks(n, g)[:, 0] for g in generators])  # [K, n, width]
            h = per_frame_linear(h * masks, layer.weight.T, layer.bias)
            if k < len(self.dropout) - 1:
                h = torch.relu(h)
        return torch.softmax(h, dim=-1)

    @classmethod
    def fit(
        cls, settings: MCDSettings, data: TrainingData, generator: torch.Generator, progress: bool = False
    ) -> Fitted:
        return cls.fit_replicates(settings, [data], [generator], progress)[0]

    @classmethod
    def fit_replicates(
        cls,
        settings: MCDSettings,
        data: Sequence[TrainingData],
        generators: Sequence[torch.Generator],
        progress: bool = False,
    ) -> list[Fitted]:
        """Adam on cross-entropy + concrete dropout regulariser, end to end on the frames, every replicate stacked
        (`StackedMCD`); replicate r's initialisation, batches and masks from ``generators[r]``."""
        train, val = shared_frames(data)
        networks = [cls(d.arch, d.bins, settings.init_p, settings.temperature) for d in data]
        stacked = StackedMCD([init_weights(n, g) for n, g in zip(networks, generators)])
        optimizer = adam(stacked.parameters(), settings.lr)
        curves: list[list[dict]] = [[] for _ in generators]
        for epoch in trange(1, settings.epochs + 1, desc="mcd", unit="epoch", disable=not progress):
            loss_sums = torch.zeros(len(generators), dtype=torch.float64)
            for index in epoch_batches(len(train), settings.batch_size, generators):
                losses = stacked.losses(*stacked.batch(train, index, generators), len(train), settings.lengthscale)
                optimizer.zero_grad()
                losses.sum().backward()
                optimizer.step()
                loss_sums += losses.detach().double() * index.shape[1]
            val_features = stacked_features(stacked.template.trunk, stacked.params, val)
            for r, (network, d, g) in enumerate(zip(stacked.networks_now(), data, generators)):
                scores = evaluate(network, val_features[r], val.labels, d.eval_samples, g)
                curves[r].append(curve_row(epoch, float(loss_sums[r]) / len(train), scores, **network.rate_metrics()))
        return [Fitted(n.requires_grad_(False), c, n.fit_metrics()) for n, c in zip(stacked.networks_now(), curves)]

    def rate_metrics(self) -> dict[str, float]:
        return {f"dropout_p{k + 1}": p for k, p in enumerate(self.dropout_rates())}

    def fit_metrics(self) -> dict:
        rates = self.dropout_rates()
        return {**self.rate_metrics(), "diagnostics": "learned dropout rates " + ", ".join(f"{p:.3f}" for p in rates)}


class StackedMCD:
    """R MCD networks of one shape trained as one (`uqdrive.models.stacking`): the trunk one grouped convolution
    per layer, the head one `baddbmm` per layer, concrete dropout with each replicate's rate and uniforms."""

    def __init__(self, networks: Sequence[MCDPosterior]) -> None:
        self.networks = list(networks)
        self.template = self.networks[0]
        self.params = stack_parameters(self.networks)

    def parameters(self) -> list[torch.Tensor]:
        return list(self.params.values())

    def networks_now(self) -> list[MCDPosterior]:
        """The replicates' networks holding the stacked parameters' current values."""
        unstack_into(self.params, self.networks)
        return self.networks

    def rates(self) -> list[torch.Tensor]:
        """Each dropout layer's rates [R]."""
        return [torch.sigmoid(self.params[f"dropout.{k}.p_logit"][:, 0]) for k in range(len(self.template.dropout))]

    def train_logits(self, frames: torch.Tensor, uniforms: Sequence[torch.Tensor]) -> torch.Tensor:
        """Training pass of frames [R, B, 1, 48, 64] with relaxed masks from uniforms [R, B, width] per dropout
        layer (differentiable in the rates): [R, B, C]."""
        params, last = self.params, len(self.template.dropout) - 1
        h = torch.relu(stacked_linear(stacked_trunk(self.template.trunk, params, frames), *self._layer(0)))
        for k, (drop, p, u) in enumerate(zip(self.template.dropout, self.rates(), uniforms)):
            h = stacked_linear(relaxed_dropout(h, p.view(-1, 1, 1), u, drop.temperature), *self._layer(k + 1))
            if k < last:
                h = torch.relu(h)
        return h

    def regularizer(self, num_train: int, lengthscale: float) -> torch.Tensor:
        """Concrete dropout's KL term per training frame of each replicate [R] (`ConcreteDropout.regularizer`)."""
        total = torch.zeros(len(self.networks))
        for k, (drop, p) in enumerate(zip(self.template.dropout, self.rates())):
            weight, bias = self._layer(k + 1)
            squares = weight.pow(2).sum((1, 2)) + bias.pow(2).sum(1)
            total = total + dropout_regularizer(squares, p, drop.width, lengthscale**2 / num_train, 2.0 / num_train)
        return total

    def batch(
        self, frames: FrameSet, index: torch.Tensor, generators: Sequence[torch.Generator]
    ) -> tuple[torch.Tensor, list[torch.Tensor], torch.Tensor]:
        """Each replicate's minibatch ``frames[index[r]]`` [R, b, 1, 48, 64], its dropout uniforms [R, b, width] per
        layer (drawn from its own generator, as its lone run draws them) and its labels [R, b]."""
        replicates, size = index.shape
        x = to_inputs(frames.images[index.flatten()]).view(replicates, size, *INPUT_SHAPE)
        uniforms = [
            per_replicate(generators, lambda g, width=drop.width: torch.rand((size, width), generator=g))
            for drop in self.template.dropout
        ]
        return x, uniforms, frames.labels[index]

    def losses(
        self, x: torch.Tensor, uniforms: list[torch.Tensor], labels: torch.Tensor, num_train: int, lengthscale: float
    ) -> torch.Tensor:
        """Each replicate's loss [R] on its minibatch (`batch`): cross-entropy + the regulariser per training frame."""
        nll = cross_entropy(self.train_logits(x, uniforms).flatten(0, 1), labels.flatten(), reduction="none")
        return nll.view(labels.shape).mean(1) + self.regularizer(num_train, lengthscale)

    def _layer(self, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        return self.params[f"head.{k}.weight"], self.params[f"head.{k}.bias"]
