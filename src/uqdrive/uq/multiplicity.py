"""Multiple-comparison correction: γ (or α) split evenly over a family (Bonferroni).

It controls the family-wise error (the probability of one or more false claims) under arbitrary
dependence between the tests or cells: it rests on the union bound only, which is what paired cells
(same seeds) and replicate-sharing comparisons need.
"""

from __future__ import annotations

import math
from fractions import Fraction

from uqdrive.uq.bounds import check_unit


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
