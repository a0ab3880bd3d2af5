"""Multiple-comparison corrections: Holm's step-down adjusted p-values, and γ split over a family of cells.

Both control the family-wise error (the probability of one or more false claims) under arbitrary
dependence between the tests or cells: they rest on the union bound only, which is what paired cells
(same seeds) and replicate-sharing comparisons need.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from uqdrive.uq.bounds import check_unit


def holm(p_values: Sequence[float] | np.ndarray) -> np.ndarray:
    """Holm's adjusted p-values: rejecting where adjusted ≤ α keeps the family-wise error ≤ α.

    With the m p-values sorted, p_(1) ≤ … ≤ p_(m), adjusted_(i) = max_{j ≤ i} min(1, (m − j + 1) p_(j)),
    returned in the input order; the running maximum makes the adjusted values monotone in the raw ones.
    """
    p = np.asarray(p_values, float)
    if p.ndim != 1 or np.any(~((p >= 0) & (p <= 1))):
        raise ValueError(f"Holm needs a 1-d sequence of p-values in [0, 1], got {p_values!r}")
    order = np.argsort(p, kind="stable")
    scaled = np.minimum(1.0, (p.size - np.arange(p.size)) * p[order])
    adjusted = np.empty_like(p)
    adjusted[order] = np.maximum.accumulate(scaled)
    return adjusted


def per_cell_gamma(gamma: float, cells: int) -> float:
    """Bonferroni: each of ``cells`` cells at γ/m, so all are within their ±θ at once with probability ≥ 1 − γ.

    The union bound needs no independence: P(some cell misses) ≤ Σ_cells P(that cell misses) ≤ m · γ/m.
    """
    gamma = check_unit("gamma", gamma)
    if isinstance(cells, bool) or int(cells) != cells or cells < 1:
        raise ValueError(f"cells must be an integer >= 1, got {cells!r}")
    return gamma / int(cells)
