"""What a comparison concludes, at either level of answer: for these trained controllers (`family`) or for the
method over its training runs (`claims`). String-valued, so a record serialises it as its text."""

from __future__ import annotations

from enum import StrEnum


class Verdict(StrEnum):
    SUPPORTED = "supported"  # the difference is established (in the claim's direction, for a method claim)
    REFUTED = "refuted"  # a method claim: the opposite direction is established
    EQUIVALENT = "equivalent"  # a method claim: the difference is established to lie within ±δ
    UNDECIDED = "undecided"  # none of the above; a reason says why


class Reason(StrEnum):
    """Why a comparison is undecided ("" where it is decided)."""

    DECIDED = ""
    NOT_SIGNIFICANT = "the interval holds 0 at this level"
    TOO_FEW_REPLICATES = "fewer than two replicates"
    NOT_DECIDED = "the mean's interval holds 0 and reaches past ±δ at this level"
    NO_BOUNDED_RANGE = "an unbounded score has no interval for its mean valid for every spread"
