"""A posterior on held-out frames: per weather × noise, accuracy, NLL, ECE and Brier score of the predictive, the
mean mutual information and η2, how well MI and 1 − η2 rank frames with a wrong class above right ones (AUROC),
and agreement with a reference posterior's predictive (HMC, the asymptotically exact one). The `evaluate` stage's
record, metrics/evaluate.json: method → weather → noise<σ> → `HeldoutCell`."""

from __future__ import annotations

import math
import zlib

import numpy as np
import torch

from uqdrive.data.datasets import FrameSet
from uqdrive.models.metrics import classification_metrics, mistake_auroc
from uqdrive.models.posterior import Posterior
from uqdrive.models.training import derived_generator
from uqdrive.records import record
from uqdrive.resolvers import noise_label
from uqdrive.uq import frame_measures


@record
class HeldoutCell:
    """One method at one weather × noise; an AUROC that is undefined (no wrong or no right frame) is None, with the
    reason in ``auroc_note``; ``hmc_*``: agreement with HMC's predictive, when HMC was evaluated (HMC's own row
    compares two independent draw sets: the Monte-Carlo noise floor)."""

    accuracy: float
    nll: float
    ece: float
    brier: float
    mean_mutual_information: float
    mean_eta2: float
    auroc_mi: float | None
    auroc_one_minus_eta2: float | None
    auroc_note: str | None
    frames: int
    mistakes: int
    hmc_tv_distance: float | None = None
    hmc_tv_distance_max: float | None = None
    hmc_argmax_agreement: float | None = None
    hmc_mi_spearman: float | None = None


@record
class HeldoutTable:
    """metrics/evaluate.json: method → weather → noise<σ> → its cell."""

    cells: dict[str, dict[str, dict[str, HeldoutCell]]]

    def cell(self, method: str, weather: str, noise: float) -> HeldoutCell:
        return self.cells[method][weather][noise_key(noise)]


def noise_key(noise: float) -> str:
    return f"noise{noise_label(noise)}"


def cell_generator(seed: int, method: str, weather: str, noise: float) -> torch.Generator:
    """A cell's draws depend on the seed and its name only: adding a weather leaves the other cells as they were."""
    key = zlib.crc32(f"{method}-{weather}-{noise_key(noise)}".encode())
    return derived_generator(seed, key)


@torch.no_grad()
def predict(
    posterior: Posterior,
    frames: FrameSet,
    samples: int,
    eps: float,
    batch_size: int,
    centres: np.ndarray,
    generator: torch.Generator,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Predictive probabilities [B, C], η2 [B] and mutual information [B] of every frame, batch by batch
    (only one batch's [samples, batch, C] draws are held at a time)."""
    probs, eta2, mi = [], [], []
    for x, _ in frames.batches(batch_size):
        draws = posterior.sample_probs(x, samples, generator)
        measures = frame_measures(draws, centres, eps)
        probs.append(draws.mean(0))
        eta2.append(measures.eta2)
        mi.append(measures.mutual_information)
    return torch.cat(probs), torch.cat(eta2), torch.cat(mi)


def heldout_cell(probs: torch.Tensor, labels: torch.Tensor, eta2: torch.Tensor, mi: torch.Tensor) -> dict:
    """The metrics of one cell (the fields of `HeldoutCell` but agreement)."""
    wrong = probs.argmax(1) != labels
    mistakes = int(wrong.sum())
    aurocs = {"auroc_mi": mistake_auroc(mi, wrong), "auroc_one_minus_eta2": mistake_auroc(1 - eta2, wrong)}
    note = None
    if mistakes in (0, len(labels)):
        note = (
            f"AUROC undefined: {'no' if mistakes == 0 else 'every'} frame of {len(labels)} has a wrong class, "
            f"and ranking mistakes above right frames needs both"
        )
    return {
        **classification_metrics(probs, labels),
        "mean_mutual_information": float(mi.mean()),
        "mean_eta2": float(eta2.mean()),
        **{k: None if math.isnan(v) else v for k, v in aurocs.items()},
        "auroc_note": note,
        "frames": len(labels),
        "mistakes": mistakes,
    }
