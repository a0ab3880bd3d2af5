"""Per-frame uncertainty measures from posterior samples of class probabilities.

Input everywhere is ``probs`` of shape ``[n, B, C]``: n weight samples of the steering
classifier, B frames, C classes, plus ``centres`` (length C), the steering value of each class.
The package knows nothing of how classes were binned; the caller passes the centres.
All functions are vectorised over samples and frames (no Python loops) and accept numpy arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy import special

PROB_SUM_TOL = 1e-4
"""How far ``probs.sum(-1)`` may stray from 1 before the input is rejected."""

_BALL_TOL = 1e-6
"""Slack on the ε-ball edge so that centres like -0.9 vs -1.0 with ε = 0.1 count as inside
despite binary rounding (|-0.9 - -1.0| = 0.09999999999999998 or 0.10000000000000009)."""

ArrayLike = torch.Tensor | np.ndarray


@dataclass(frozen=True)
class FrameMeasures:
    """Everything a controller needs per frame; each field has shape ``[B]``."""

    decision: torch.Tensor
    eta2: torch.Tensor
    mutual_information: torch.Tensor
    mutual_information_se: torch.Tensor
    entropy: torch.Tensor
    steering_mean: torch.Tensor
    steering_var: torch.Tensor


def check_samples(probs: ArrayLike, centres: ArrayLike | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Return ``probs`` (and ``centres``) as floating tensors, or raise ``ValueError`` naming the bad input.

    Checks: ``probs`` is 3-D ``[n, B, C]`` with n, B, C ≥ 1, finite, non-negative, sums to 1
    along C within ``PROB_SUM_TOL``; ``centres`` is 1-D of length C and finite.
    """
    p = torch.as_tensor(probs)
    if p.ndim != 3:
        raise ValueError(f"probs must have shape [n, B, C] (3-D), got shape {tuple(p.shape)}")
    if min(p.shape) < 1:
        raise ValueError(f"probs must have n, B, C >= 1, got shape {tuple(p.shape)}")
    if not p.is_floating_point():
        p = p.to(torch.get_default_dtype())
    if not _valid_probs(p):
        _reject(p)
    if centres is None:
        return p, None
    c = torch.as_tensor(centres, dtype=p.dtype)
    if c.ndim != 1 or c.shape[0] != p.shape[-1]:
        raise ValueError(
            f"centres must be 1-D with length C={p.shape[-1]} (the last axis of probs), got shape {tuple(c.shape)}"
        )
    if not torch.isfinite(c).all():
        raise ValueError("centres must be finite, got NaN or inf")
    return p, c


def _valid_probs(p: torch.Tensor) -> bool:
    """Non-negative rows summing to 1 within tolerance, in three reductions (a controller checks every frame).

    That also proves every entry finite: a NaN makes its row sum NaN (and the comparison false), +inf its
    row sum inf, −inf the minimum; `_reject` then finds which check failed."""
    return bool(p.min() >= 0) and bool((p.sum(-1) - 1).abs().max() <= PROB_SUM_TOL)


def _reject(p: torch.Tensor) -> None:
    """Raise the error naming the first check ``p`` fails."""
    if not torch.isfinite(p).all():
        raise ValueError("probs must be finite, got NaN or inf")
    if (p < 0).any():
        raise ValueError(f"probs must be >= 0, got minimum {p.min().item():.6g}")
    dev = (p.sum(-1) - 1).abs()
    if dev.max().item() > PROB_SUM_TOL:
        i, b = np.unravel_index(int(dev.argmax()), dev.shape)
        raise ValueError(
            f"probs must sum to 1 along C (tolerance {PROB_SUM_TOL}), got sum "
            f"{p[i, b].sum().item():.6g} at sample {i}, frame {b}"
        )


def _check_eps(eps: float) -> float:
    try:
        e = float(eps)
    except (TypeError, ValueError):
        e = math.nan
    if not (math.isfinite(e) and e > 0):
        raise ValueError(f"eps must be a finite number > 0 (steering units), got {eps!r}")
    return e


def within_ball(decisions: ArrayLike, pi: ArrayLike | float, eps: float) -> ArrayLike:
    """Is each decision within ``eps`` of ``pi`` (closed ball, with `_BALL_TOL`)? numpy or torch, as given."""
    return abs(decisions - pi) <= eps * (1 + _BALL_TOL)


def _inside(p: torch.Tensor, c: torch.Tensor, pi: torch.Tensor, eps: float) -> torch.Tensor:
    return within_ball(c[p.argmax(-1)], pi, eps)


def _eta2(p: torch.Tensor, c: torch.Tensor, pi: torch.Tensor, eps: float) -> torch.Tensor:
    return _inside(p, c, pi, eps).to(p.dtype).mean(0)


def _entropy(p: torch.Tensor) -> torch.Tensor:
    """Shannon entropy in nats along the last axis; 0·log 0 = 0."""
    return -torch.special.xlogy(p, p).sum(-1)


def predictive_probs(probs: ArrayLike) -> torch.Tensor:
    """Posterior predictive class probabilities ``[B, C]``: the mean over weight samples."""
    p, _ = check_samples(probs)
    return p.mean(0)


def decision(probs: ArrayLike, centres: ArrayLike) -> torch.Tensor:
    """π(o) per frame ``[B]``: the centre of the most probable class of the predictive distribution."""
    p, c = check_samples(probs, centres)
    return c[p.mean(0).argmax(-1)]


def sample_decisions(probs: ArrayLike, centres: ArrayLike) -> torch.Tensor:
    """Each weight sample's decision ``[n, B]``: the centre of its own argmax class."""
    p, c = check_samples(probs, centres)
    return c[p.argmax(-1)]


def decision_confidence(probs: ArrayLike, centres: ArrayLike, eps: float, pi: ArrayLike | None = None) -> torch.Tensor:
    """Real-time decision confidence η2 per frame ``[B]`` (the paper's Definition 2).

    η2 = fraction of weight samples whose decision lies within ``eps`` (steering units, closed
    ball) of π(o); ``pi`` defaults to :func:`decision` of these same samples. Given a ``pi``
    chosen independently of ``probs`` (the controller draws π(o) from other samples), each
    sample's "inside the ball" is a Bernoulli draw with rate η2, so the fraction over n samples
    is the estimator η̂2 of the paper, and with n ≥ ``chernoff_n(theta, gamma)`` samples
    P(|η̂2 − η2| > θ) ≤ γ (Chernoff–Hoeffding); the estimators in :mod:`uqdrive.uq.estimators`
    apply unchanged to its count. With the default ``pi`` the mode is picked where these draws
    agree, so the fraction is biased upwards and the bound is not claimed.
    """
    e = _check_eps(eps)
    p, c = check_samples(probs, centres)
    ref = c[p.mean(0).argmax(-1)] if pi is None else torch.as_tensor(pi, dtype=p.dtype)
    if ref.shape != p.shape[1:2]:
        raise ValueError(f"pi must have shape [B]=({p.shape[1]},), got {tuple(ref.shape)}")
    return _eta2(p, c, ref, e)


def predictive_entropy(probs: ArrayLike) -> torch.Tensor:
    """Entropy (nats) of the predictive distribution per frame ``[B]``: total uncertainty."""
    return _entropy(predictive_probs(probs))


def expected_entropy(probs: ArrayLike) -> torch.Tensor:
    """Mean over weight samples of each sample's entropy (nats) ``[B]``: the aleatoric part."""
    p, _ = check_samples(probs)
    return _entropy(p).mean(0)


def mutual_information(probs: ArrayLike) -> torch.Tensor:
    """Mutual information between class and weights (nats) ``[B]``: the epistemic part.

    Predictive entropy minus expected entropy; ≥ 0 by Jensen, so rounding noise is clamped to 0.
    """
    p, _ = check_samples(probs)
    return (_entropy(p.mean(0)) - _entropy(p).mean(0)).clamp_min(0)


def mutual_information_se(probs: ArrayLike) -> torch.Tensor:
    """Jackknife standard error ``[B]`` of :func:`mutual_information` from these n draws: how precise the plug-in
    MI is at the draws made (0 when all draws agree exactly; NaN for a single draw). An approximate standard
    error, not a bound: the plug-in MI is biased low at small n, by more than this where the draws disagree.
    """
    p, _ = check_samples(probs)
    return _mutual_information_se(p, _entropy(p))


def _mutual_information_se(p: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    """The jackknife from draws ``p`` [n, B, C] and their entropies ``h`` [n, B]."""
    n = len(p)
    if n < 2:
        return torch.full(p.shape[1:2], math.nan, dtype=p.dtype)
    q_without = (p.sum(0) - p) / (n - 1)  # [n, B, C]: the predictive without draw i
    mi_without = _entropy(q_without) - (h.sum(0) - h) / (n - 1)
    return ((n - 1) / n * (mi_without - mi_without.mean(0)).square().sum(0)).sqrt()


def draw_measures(probs: np.ndarray) -> tuple[float, float, float]:
    """(mutual information, its jackknife standard error, predictive entropy) of one frame's draws [n, C], in
    numpy: a controller's sequential draws take these per frame on a few dozen draws, where a numpy call costs
    a fraction of a torch call. The numbers of :func:`frame_measures` within float rounding (a test checks it).
    Raises ``ValueError`` for draws that are not probabilities, as :func:`check_samples` does."""
    p = np.asarray(probs, dtype=np.float64)
    if p.ndim != 2 or not (p.min() >= 0 and np.abs(p.sum(-1) - 1).max() <= PROB_SUM_TOL):
        check_samples(p[:, None] if p.ndim == 2 else p)  # names the failing check
    n = len(p)
    h = -special.xlogy(p, p).sum(-1)  # [n]
    total = p.sum(0)
    q = total / n
    entropy = float(-special.xlogy(q, q).sum())
    mi = max(entropy - float(h.mean()), 0.0)
    if n < 2:
        return mi, math.nan, entropy
    q_without = (total - p) / (n - 1)
    mi_without = -special.xlogy(q_without, q_without).sum(-1) - (h.sum() - h) / (n - 1)
    return mi, float(np.sqrt((n - 1) / n * np.square(mi_without - mi_without.mean()).sum())), entropy


def steering_moments(probs: ArrayLike, centres: ArrayLike) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and variance ``[B]`` of steering under the posterior *predictive* (mixture over samples).

    The variance is the total one (law of total variance: within-sample spread plus spread of
    the samples' means), not the variance of the samples' argmax decisions.
    """
    p, c = check_samples(probs, centres)
    q = p.mean(0)
    mean = q @ c
    var = (q * (c - mean[:, None]) ** 2).sum(-1)
    return mean, var


def frame_measures(probs: ArrayLike, centres: ArrayLike, eps: float, split: int | None = None) -> FrameMeasures:
    """All per-frame measures at once (validates the input once, shares the predictive).

    ``split``: draws ``[:split]`` give π(o) and every other measure (the MI's standard error:
    :func:`mutual_information_se`), draws ``[split:]`` give η2 around that π(o) (as :func:`decision_confidence`
    with ``pi``): the controller's separate draws, which make η̂2 a binomial mean given π(o). The same numbers as
    the single functions, from one check of the input.
    """
    e = _check_eps(eps)
    p, c = check_samples(probs, centres)
    if split is not None and not 0 < split < len(p):
        raise ValueError(f"split={split!r} must leave draws on both sides: 0 < split < n={len(p)}")
    p, confidence = (p, p) if split is None else (p[:split], p[split:])
    q = p.mean(0)
    pi = c[q.argmax(-1)]
    h = _entropy(q)
    each = _entropy(p)
    mean = q @ c
    return FrameMeasures(
        decision=pi,
        eta2=_eta2(confidence, c, pi, e),
        mutual_information=(h - each.mean(0)).clamp_min(0),
        mutual_information_se=_mutual_information_se(p, each),
        entropy=h,
        steering_mean=mean,
        steering_var=(q * (c - mean[:, None]) ** 2).sum(-1),
    )
