"""Deep ensemble (Lakshminarayanan et al. 2017) of heads on the fixed MCD trunk.

M heads from independent He initialisations, each trained to a MAP (same N(0, σ²) prior as VI
and HMC) with its own minibatch order; all M train side by side as a batch dimension. The
predictive is the uniform mixture of the members, so a draw is a member: draws run through a
random permutation of the members, cyclically (n ≤ M: distinct members; n > M: every member
⌊n/M⌋ or ⌈n/M⌉ times). Averages over such draws are unbiased for the mixture and vary less than
with independent draws (sampling without replacement; Hoeffding's bound still holds for it).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated

import torch
from pydantic import Field

from uqdrive.models.heads import StoredHeadPosterior, he_init_heads, train_heads
from uqdrive.models.posterior import Fitted
from uqdrive.models.training import TrainingData, share_features, shared_frames
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
        return cls.fit_replicates(settings, [data], [generator], progress)[0]

    @classmethod
    def fit_replicates(
        cls,
        settings: EnsembleSettings,
        data: Sequence[TrainingData],
        generators: Sequence[torch.Generator],
        progress: bool = False,
    ) -> list[Fitted]:
        """Every replicate's members trained side by side, replicate r's on its own base model's features."""
        train, val = shared_frames(data)
        features, val_features = share_features(data)
        shapes = data[0].base.arch.head_shapes(data[0].base.num_classes)
        ensembles = [
            cls.from_heads(d.base, he_init_heads(settings.members, shapes, g)) for d, g in zip(data, generators)
        ]
        members, curves = train_heads(
            torch.stack([e.samples for e in ensembles]),
            shapes,
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
            desc="ensemble",
            scored=ensembles,
            eval_samples=settings.members,
        )
        extra = {
            "members": settings.members,
            "diagnostics": f"{settings.members} members from independent initialisations",
        }
        fitted = []
        for ensemble, heads, curve in zip(ensembles, members, curves):
            ensemble.load_heads(heads)
            fitted.append(Fitted(ensemble, curve, dict(extra)))
        return fitted
