"""Convergence of sampled posteriors judged where it matters: in function space.

A network's weights are not identifiable (permuting hidden units gives the same function), so
weight-space R̂ says little; what the controller uses are the predictive class probabilities
and the mutual information of each frame. Rank-normalised split-R̂ and bulk/tail effective
sample sizes (Vehtari et al. 2021) come from ArviZ, over chains × draws of:
- p_s(c | frame): the class probabilities of draw s, for every (frame, class) pair whose
  predictive probability exceeds `min_prob` (R̂ of a probability that is always ~0 is noise);
- KL(p_s ‖ p̄) per frame, whose mean over draws is exactly the frame's mutual information
  (I = H[p̄] − E_s H[p_s] = E_s KL(p_s ‖ p̄)): its R̂/ESS are those of the MI estimate.
"""

from __future__ import annotations

import warnings

import numpy as np
import torch

RHAT_OK = 1.1  # the usual threshold (Gelman et al., BDA3); Vehtari et al. 2021 suggest 1.01 for final results


def _arviz_diagnostics(draws: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rank-normalised split-R̂, bulk ESS and tail ESS per column of draws [chains, S, K]."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # arviz announces its refactor on import
        import arviz as az
    data = az.convert_to_dataset(np.ascontiguousarray(draws, dtype=np.float64))
    return (
        az.rhat(data, method="rank")["x"].values,
        az.ess(data, method="bulk")["x"].values,
        az.ess(data, method="tail")["x"].values,
    )


def per_draw_mutual_information(probs: torch.Tensor) -> torch.Tensor:
    """KL(p_s ‖ p̄) [chains, S, B] for probs [chains, S, B, C]; its mean over chains × S is each frame's MI."""
    p = probs.double().clamp_min(1e-12)
    mean = p.mean((0, 1), keepdim=True)
    return (p * (p.log() - mean.log())).sum(-1)


def function_space_diagnostics(probs: torch.Tensor, min_prob: float = 0.01) -> dict[str, float]:
    """R̂ and ESS of probs [chains, S, B, C] over the (frame, class) pairs with mean probability > min_prob,
    and of each frame's mutual information; shares are of pairs (frames) with R̂ ≤ 1.1."""
    if probs.ndim != 4 or probs.shape[0] < 2 or probs.shape[1] < 4:
        raise ValueError(
            f"function_space_diagnostics needs probs [chains ≥ 2, draws ≥ 4, frames, classes], got {list(probs.shape)}"
        )
    chains, draws = probs.shape[:2]
    flat = probs.reshape(chains, draws, -1)
    used = flat.mean((0, 1)) > min_prob
    rhat, bulk, tail = _arviz_diagnostics(flat[:, :, used].numpy())
    mi_rhat, mi_bulk, mi_tail = _arviz_diagnostics(per_draw_mutual_information(probs).numpy())
    return {
        "fs_pairs": int(used.sum()),
        "fs_rhat_share_ok": float(np.mean(rhat <= RHAT_OK)),
        "fs_rhat_median": float(np.median(rhat)),
        "fs_rhat_max": float(np.max(rhat)),
        "fs_ess_bulk_min": float(np.min(bulk)),
        "fs_ess_bulk_median": float(np.median(bulk)),
        "fs_ess_tail_min": float(np.min(tail)),
        "mi_rhat_share_ok": float(np.mean(mi_rhat <= RHAT_OK)),
        "mi_rhat_median": float(np.median(mi_rhat)),
        "mi_rhat_max": float(np.max(mi_rhat)),
        "mi_ess_bulk_min": float(np.min(mi_bulk)),
        "mi_ess_tail_min": float(np.min(mi_tail)),
        "draws_total": int(chains * draws),
    }


def between_chain_mi_share(probs: torch.Tensor) -> float:
    """Share of the mean MI that is disagreement *between* chains (MI of the chains' mean predictives):
    near 0 when chains sample the same distribution, large when each sits in its own region."""
    p = probs.double().clamp_min(1e-12)
    total = per_draw_mutual_information(probs).mean((0, 1))
    per_chain = p.mean(1)  # [chains, B, C]
    overall = per_chain.mean(0, keepdim=True)
    between = (per_chain * (per_chain.log() - overall.log())).sum(-1).mean(0)
    return float(between.sum() / total.sum().clamp_min(1e-300))
