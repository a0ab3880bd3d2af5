"""What every method's `fit` shares: its data, the trunk-feature cache and evaluation.

Head methods (VI, HMC, ensemble, Laplace) only ever see the base (MCD) model's trunk features,
which are fixed, so `TrainingData` runs the convolutions once per split and every epoch /
leapfrog step reuses the tensor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import FrameSet
from uqdrive.models.checkpoint import load_posterior
from uqdrive.models.metrics import classification_metrics
from uqdrive.models.pilotnet import Architecture
from uqdrive.models.posterior import Posterior
from uqdrive.models.stacking import FEATURE_ROWS, stacked_features, stacked_trunks

EVAL_CHUNK = 2048  # frames per head evaluation: bounds memory at n draws x chunk x classes
BASE_METHOD = "mcd"  # the model whose trunk (and head, as a start) the head methods build on
VALIDATION_STREAM = 0x76616C  # "val": the reported validation draws' stream, apart from the fit's own


@dataclass
class TrainingData:
    """The train stage's inputs as a method sees them; the base model and its features load on first use."""

    train: FrameSet
    val: FrameSet
    bins: SteeringBins
    arch: Architecture  # widths of a network trained from scratch
    base_model: Path  # models/mcd.pt: the fixed trunk of every head method
    eval_samples: int  # posterior draws per validation frame for curves and metrics

    @cached_property
    def base(self) -> Posterior:
        return load_posterior(self.base_model, expected_method=BASE_METHOD, expected_classes=self.bins)

    @cached_property
    def train_features(self) -> torch.Tensor:
        return compute_features(self.base, self.train)

    @cached_property
    def val_features(self) -> torch.Tensor:
        return compute_features(self.base, self.val)


def share_features(data: Sequence[TrainingData]) -> tuple[torch.Tensor, torch.Tensor]:
    """Every replicate's train and validation features [R, N, F] from its base model's trunk: those not yet cached
    computed with the trunks stacked (`stacked_features`), each replicate's `train_features` and `val_features`
    then holding its own rows."""
    train, val = shared_frames(data)
    missing = [d for d in data if not {"train_features", "val_features"} <= vars(d).keys()]
    if missing:
        bases = [d.base for d in missing]
        params = stacked_trunks(bases)
        computed = stacked_features(bases[0].trunk, params, train), stacked_features(bases[0].trunk, params, val)
        for d, train_features, val_features in zip(missing, *computed):
            d.train_features, d.val_features = train_features, val_features
    return torch.stack([d.train_features for d in data]), torch.stack([d.val_features for d in data])


def shared_frames(data: Sequence[TrainingData]) -> tuple[FrameSet, FrameSet]:
    """The train and validation frames of replicates trained as one batch: the same frames (each replicate shuffles
    them its own way), network shape and evaluation, or stacking them means nothing."""
    first = data[0]
    for other in data[1:]:
        if other.train is not first.train or other.val is not first.val:
            raise ValueError("replicates trained as one batch must share their train and validation frames")
        if (other.arch, other.bins, other.eval_samples) != (first.arch, first.bins, first.eval_samples):
            raise ValueError("replicates trained as one batch must share their architecture, classes and eval_samples")
    return first.train, first.val


@torch.no_grad()
def compute_features(posterior: Posterior, frames: FrameSet, batch_size: int = FEATURE_ROWS) -> torch.Tensor:
    """Trunk outputs [N, F] of every frame, in order: the cache the head methods train on."""
    return torch.cat([posterior.features(x) for x, _ in frames.batches(batch_size)])


@torch.no_grad()
def evaluate(
    posterior: Posterior, features: torch.Tensor, labels: torch.Tensor, n: int, generator: torch.Generator
) -> dict[str, float]:
    """Metrics of the posterior predictive (mean of n draws' probabilities) on cached features."""
    probs = torch.cat([posterior.head_probs(f, n, generator).mean(0) for f in features.split(EVAL_CHUNK)])
    return classification_metrics(probs, labels)


def derived_generator(*entropy: int) -> torch.Generator:
    """A torch generator seeded from a seed sequence over ``entropy``: independent streams per distinct tuple."""
    return torch.Generator().manual_seed(int(np.random.SeedSequence(list(entropy)).generate_state(1)[0]))


def validation_generator(seed: int) -> torch.Generator:
    """The draws behind a replicate's reported validation metrics: a function of its seed alone, so whoever reloads
    the saved model reproduces the number exactly (the fit's generator ends wherever training left it)."""
    return derived_generator(seed, VALIDATION_STREAM)


def curve_row(step: int, train_loss: float, scores: dict[str, float], **extra: float) -> dict:
    return {
        "step": step,
        "train_loss": train_loss,
        "val_accuracy": scores["accuracy"],
        "val_nll": scores["nll"],
        **extra,
    }
