"""How closely a method's predictive matches a reference posterior's (HMC's) on the same frames.

Per frame: total-variation distance ½‖p − p_ref‖₁ between the predictive distributions and
whether their argmax (the controller's decision) agrees; over the frames: Spearman's rank
correlation of mutual information, i.e. whether the method finds the same frames uncertain (the
warnings act on that ranking, not on MI's scale).
"""

from __future__ import annotations

import math

import torch
from scipy.stats import spearmanr


def agreement_with_reference(
    probs: torch.Tensor, mi: torch.Tensor, reference_probs: torch.Tensor, reference_mi: torch.Tensor
) -> dict[str, float | None]:
    """probs, reference_probs [B, C] (predictive means); mi, reference_mi [B]. Spearman is None when either
    MI is constant over the frames (a rank correlation is undefined then)."""
    if probs.shape != reference_probs.shape or mi.shape != reference_mi.shape or len(mi) != len(probs):
        raise ValueError(
            f"agreement needs matching shapes, got probs {list(probs.shape)} vs "
            f"{list(reference_probs.shape)}, MI {list(mi.shape)} vs {list(reference_mi.shape)}"
        )
    tv = 0.5 * (probs.double() - reference_probs.double()).abs().sum(1)
    rho = spearmanr(mi.double().numpy(), reference_mi.double().numpy()).statistic if len(mi) > 1 else math.nan
    return {
        "tv_distance": float(tv.mean()),
        "tv_distance_max": float(tv.max()),
        "argmax_agreement": float((probs.argmax(1) == reference_probs.argmax(1)).double().mean()),
        "mi_spearman": None if math.isnan(rho) else float(rho),
    }
