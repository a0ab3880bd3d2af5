"""Validation metrics of a posterior predictive: is it right (accuracy), and is it honest (NLL, ECE, Brier)?"""

from __future__ import annotations

import torch

ECE_BINS = 15


def classification_metrics(probs: torch.Tensor, labels: torch.Tensor) -> dict[str, float]:
    """Accuracy, NLL, expected calibration error (15 equal-width confidence bins) and Brier score.

    probs: predictive class probabilities [B, C] (the mean over posterior draws); labels [B].
    """
    probs = probs.double().clamp_min(1e-12)
    confidence, predicted = probs.max(1)
    correct = (predicted == labels).double()
    bins = torch.clamp((confidence * ECE_BINS).long(), max=ECE_BINS - 1)
    gap = torch.zeros(ECE_BINS, dtype=torch.float64).index_add_(0, bins, confidence - correct)
    onehot = torch.nn.functional.one_hot(labels, probs.shape[1]).double()
    return {
        "accuracy": float(correct.mean()),
        "nll": float(-torch.log(probs.gather(1, labels[:, None])).mean()),
        "ece": float(gap.abs().sum() / len(labels)),
        "brier": float((probs - onehot).square().sum(1).mean()),
    }


def majority_accuracy(train_labels: torch.Tensor, val_labels: torch.Tensor, num_classes: int) -> float:
    """Validation accuracy of always predicting the most frequent training class: the bar to beat."""
    majority = int(torch.bincount(train_labels, minlength=num_classes).argmax())
    return float((val_labels == majority).double().mean())
