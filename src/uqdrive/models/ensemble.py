"""Deep ensemble (Lakshminarayanan et al. 2017) of heads on the fixed MCD trunk.

M heads from independent He initialisations, each trained to a MAP (same N(0, σ²) prior as VI
and HMC) with its own minibatch order; all M train side by side as a batch dimension. The
predictive is the uniform mixture of the members, so a draw is a member: draws run through a
random permutation of the members, cyclically (n ≤ M: distinct members; n > M: every member
⌊n/M⌋ or ⌈n/M⌉ times). Averages over such draws are unbiased for the mixture and vary less than
with independent draws (sampling without replacement; Hoeffding's bound still holds for it).
"""

from __future__ import annotations

from typing import Annotated

import torch
from pydantic import Field

from uqdrive.models.heads import StoredHeadPosterior, he_init_heads, train_heads
from uqdrive.models.posterior import Fitted
from uqdrive.models.training import TrainingData
from uqdrive.schema import Count, Int, Positive, schema


@schema(frozen=True)
class EnsembleSettings:
    members: Annotated[Int, Field(ge=2)]
    epochs: Count
    batch_size: Count
    lr: Positive
    prior_sigma: Positive = 1.0  # same prior as VI and HMC (MAP training)


class EnsemblePosterior(StoredHeadPosterior):
    method = "ensemble"
    Settings = EnsembleSettings

    def draw_index(self, n: int, generator: torch.Generator | None) -> torch.Tensor:
        members = len(self.samples)
        return torch.randperm(members, generator=generator)[torch.arange(n) % members]

    @classmethod
    def fit(
        cls, settings: EnsembleSettings, data: TrainingData, generator: torch.Generator, progress: bool = False
    ) -> Fitted:
        base = data.base
        shapes = base.arch.head_shapes(base.num_classes)
        ensemble = cls.from_heads(base, he_init_heads(settings.members, shapes, generator))
        members, curve = train_heads(
            ensemble.samples,
            shapes,
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
            desc="ensemble",
            scored=ensemble,
            eval_samples=settings.members,
        )
        ensemble.load_heads(members)
        return Fitted(
            ensemble,
            curve,
            {
                "members": settings.members,
                "diagnostics": f"{settings.members} members from independent initialisations",
            },
        )
