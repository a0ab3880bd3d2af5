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
from uqdrive.models.concrete_dropout import ConcreteDropout
from uqdrive.models.pilotnet import Architecture, init_weights
from uqdrive.models.posterior import Fitted, Posterior, check_draws, per_frame_linear
from uqdrive.models.training import TrainingData, compute_features, curve_row, evaluate
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

    def train_logits(self, x: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        """Training pass with relaxed per-element masks (differentiable in the rates): [B, C]."""
        h = torch.relu(self.head[0](self.trunk(x)))
        for k, (drop, layer) in enumerate(zip(self.dropout, self.head[1:])):
            h = layer(drop.relaxed(h, generator))
            if k < len(self.dropout) - 1:
                h = torch.relu(h)
        return h

    def regularizer(self, num_train: int, lengthscale: float) -> torch.Tensor:
        """Concrete dropout's KL term per training frame (weight decay l²/N, dropout term 2/N)."""
        return sum(
            drop.regularizer(layer, lengthscale**2 / num_train, 2.0 / num_train)
            for drop, layer in zip(self.dropout, self.head[1:])
        )

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
        """Adam on cross-entropy + concrete dropout regulariser, end to end on the frames."""
        model = init_weights(cls(data.arch, data.bins, settings.init_p, settings.temperature), generator)
        optimizer = torch.optim.Adam(model.parameters(), lr=settings.lr)
        curve = []
        for epoch in trange(1, settings.epochs + 1, desc="mcd", unit="epoch", disable=not progress):
            model.train()
            total = 0.0
            for x, y in data.train.batches(settings.batch_size, generator):
                loss = cross_entropy(model.train_logits(x, generator), y) + model.regularizer(
                    len(data.train), settings.lengthscale
                )
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
                total += loss.item() * len(y)
            model.eval()
            scores = evaluate(model, compute_features(model, data.val), data.val.labels, data.eval_samples, generator)
            rates = {f"dropout_p{k + 1}": p for k, p in enumerate(model.dropout_rates())}
            curve.append(curve_row(epoch, total / len(data.train), scores, **rates))
        model.requires_grad_(False)
        rates = model.dropout_rates()
        return Fitted(
            model,
            curve,
            {
                **{f"dropout_p{k + 1}": p for k, p in enumerate(rates)},
                "diagnostics": "learned dropout rates " + ", ".join(f"{p:.3f}" for p in rates),
            },
        )
