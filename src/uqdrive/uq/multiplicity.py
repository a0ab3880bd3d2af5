"""Multiple-comparison corrections: Holm's step-down procedure (adjusted p-values, and the level it grants each
hypothesis), and γ (or α) split evenly over a family (Bonferroni).

Both control the family-wise error (the probability of one or more false claims) under arbitrary
dependence between the tests or cells: they rest on the union bound only, which is what paired cells
(same seeds) and replicate-sharing comparisons need.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from fractions import Fraction

import numpy as np

from uqdrive.uq.bounds import check_unit


def _p_values(p_values: Sequence[float] | np.ndarray) -> np.ndarray:
    p = np.asarray(p_values, float)
    if p.ndim != 1 or p.size == 0 or np.any(~((p >= 0) & (p <= 1))):
        raise ValueError(f"Holm needs a non-empty 1-d sequence of p-values in [0, 1], got {p_values!r}")
    return p


def holm(p_values: Sequence[float] | np.ndarray) -> np.ndarray:
    """Holm's adjusted p-values: rejecting where adjusted ≤ α keeps the family-wise error ≤ α.

    With the m p-values sorted, p_(1) ≤ … ≤ p_(m), adjusted_(i) = max_{j ≤ i} min(1, (m − j + 1) p_(j)),
    returned in the input order; the running maximum makes the adjusted values monotone in the raw ones.
    """
    p = _p_values(p_values)
    order = np.argsort(p, kind="stable")
    scaled = np.minimum(1.0, (p.size - np.arange(p.size)) * p[order])
    adjusted = np.empty_like(p)
    adjusted[order] = np.maximum.accumulate(scaled)
    return adjusted


def holm_levels(p_values: Sequence[float] | np.ndarray, alpha: float) -> np.ndarray:
    """The level Holm's procedure at family-wise error α grants each hypothesis: rejected ⇔ p ≤ its level.

    With the p-values sorted (ties in input order), j a position (1-based) and j* the first position Holm does
    not reject (m + 1 if it rejects all), level_j = α / (m − min(j, j*) + 1): a rejected hypothesis gets the
    α / (m − j + 1) it was tested at, every other the level of the first non-rejection, which its p exceeds.
    Returned in the input order; a hypothesis's interval inverted at its level excludes the null value
    exactly when Holm rejects it.
    """
    alpha = check_unit("alpha", alpha)
    p = _p_values(p_values)
    order = np.argsort(p, kind="stable")
    levels = alpha / (p.size - np.arange(p.size))
    failed = p[order] > levels
    first_failure = int(np.argmax(failed)) if failed.any() else p.size
    granted = np.empty_like(p)
    granted[order] = np.where(np.arange(p.size) < first_failure, levels, levels[min(first_failure, p.size - 1)])
    return granted


def split_gamma(gamma: float, parts: int) -> float:
    """Bonferroni: each of ``parts`` members of a family (cells, claims, an envelope's regions) at γ/m, so all hold
    at once with probability ≥ 1 − γ; the share is rounded down until m of it, summed exactly as stored, are ≤ γ.

    The union bound needs no independence: P(some member errs) ≤ Σ P(that member errs) ≤ m · γ/m. The one helper
    every stage splits γ with.
    """
    gamma = check_unit("gamma", gamma)
    if isinstance(parts, bool) or int(parts) != parts or parts < 1:
        raise ValueError(f"parts must be an integer >= 1, got {parts!r}")
    share = gamma / int(parts)
    while Fraction(share) * int(parts) > Fraction(gamma):
        share = math.nextafter(share, 0.0)
    return share
