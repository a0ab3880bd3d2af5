"""Metrics of a posterior predictive: is it right (accuracy), is it honest (NLL, ECE, Brier), and does
its uncertainty flag its mistakes (AUROC)?

Accuracy, ECE and AUROC come from torchmetrics, so binning, tie and edge conventions are a maintained
library's. torchmetrics has no NLL or Brier score on probabilities: NLL is torch's `nll_loss` on the
log-probabilities, Brier the one-line definition (sum over classes, range [0, 2], as scikit-learn's
multiclass `brier_score_loss`).

torchmetrics is imported where a metric is computed: the import takes about 1 s, and every closed-loop stage and
rollout worker imports this module (through the posterior classes) without computing a metric.
"""

from __future__ import annotations

import math

import torch
from torch.nn.functional import nll_loss, one_hot

ECE_BINS = 15
PROB_FLOOR = 1e-12
"""Probabilities are floored here inside the NLL: a float32 softmax can underflow to 0 on a confident
wrong frame, and one infinite term would hide every other frame (the cap is -log(1e-12) ≈ 27.6 nats)."""


def classification_metrics(probs: torch.Tensor, labels: torch.Tensor) -> dict[str, float]:
    """Accuracy, NLL, expected calibration error (15 equal-width top-label confidence bins, L1) and Brier score.

    probs: predictive class probabilities [B, C] (the mean over posterior draws); labels [B].
    """
    from torchmetrics.functional.classification import multiclass_accuracy, multiclass_calibration_error

    probs, labels = probs.double(), labels.long()
    num_classes = probs.shape[1]
    return {
        "accuracy": float(multiclass_accuracy(probs, labels, num_classes, average="micro")),
        "nll": float(nll_loss(probs.clamp_min(PROB_FLOOR).log(), labels)),
        "ece": float(multiclass_calibration_error(probs, labels, num_classes, n_bins=ECE_BINS, norm="l1")),
        "brier": float((probs - one_hot(labels, num_classes)).square().sum(1).mean()),
    }


def mistake_auroc(uncertainty: torch.Tensor, wrong: torch.Tensor) -> float:
    """AUROC of a per-frame uncertainty score for predicting a wrong class (``wrong`` = 1): 1.0 when every
    mistake is more uncertain than every correct frame, 0.5 no better than chance, ties count half.

    NaN when the frames hold no mistake or no correct prediction: the ROC curve needs both (torchmetrics
    would return 0 with a warning, which reads as a perfectly wrong ranking).
    """
    wrong = wrong.bool()
    if wrong.all() or not wrong.any():
        return math.nan
    from torchmetrics.functional.classification import binary_auroc

    return float(binary_auroc(uncertainty.double(), wrong.long(), thresholds=None))


def reliability_bins(probs: torch.Tensor, labels: torch.Tensor, n_bins: int = ECE_BINS) -> dict[str, torch.Tensor]:
    """The reliability diagram behind the ECE: per equal-width top-label confidence bin ``[k/n, (k+1)/n)``
    (the last one closed), its frames, mean confidence and accuracy (NaN where empty).

    Σ frames/B · |accuracy − confidence| is the ECE of `classification_metrics` (torchmetrics gives
    confidence exactly 1.0 a bin of its own; here it joins the top bin).
    """
    confidence, predicted = probs.double().max(1)
    correct = (predicted == labels).double()
    edges = torch.linspace(0, 1, n_bins + 1, dtype=torch.float64)
    index = (torch.bucketize(confidence, edges, right=True) - 1).clamp(0, n_bins - 1)
    frames = torch.bincount(index, minlength=n_bins).double()
    return {
        "low": edges[:-1],
        "high": edges[1:],
        "frames": frames,
        "confidence": torch.bincount(index, confidence, minlength=n_bins) / frames,
        "accuracy": torch.bincount(index, correct, minlength=n_bins) / frames,
    }


def majority_accuracy(train_labels: torch.Tensor, val_labels: torch.Tensor, num_classes: int) -> float:
    """Validation accuracy of always predicting the most frequent training class: the bar to beat."""
    majority = int(torch.bincount(train_labels, minlength=num_classes).argmax())
    return float((val_labels == majority).double().mean())
