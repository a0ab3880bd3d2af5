"""The rare stage's result (`RareResult`) and what a run returns (`RareRun`). The stage function is
`uqdrive.pipeline.rare_stage`'s."""

from __future__ import annotations

import dataclasses

from uqdrive.uq.rare import FailureEstimate


@dataclasses.dataclass(frozen=True)
class RareResult:
    """The stage's record: the claim, the refutation (``refuted`` shows η1 < target over the domain with error
    ≤ γ; ``lower_bound``: on the failure probability p = 1 − η1), the importance-sampled estimate of p from the
    same rollouts (``estimate``: `FailureEstimate`, two-sided intervals, one labelled with its assumption), the
    certification (``certified``: above, below, undecided or not_run) and the failures found, each with its seed
    and condition for replay."""

    method: str
    replicate: int
    target: float
    gamma: float
    domain: dict[str, list[float]]
    refuted: bool
    refute_rollouts: int
    failures: int
    lower_bound: float
    estimate: FailureEstimate
    certified: str
    certify_rollouts: int
    failure_records: list[dict[str, float]]  # each failure: its seed, its value on each axis, its weight
    seconds: float


@dataclasses.dataclass(frozen=True)
class RareRun:
    """The record and whether it was ``reused``: every rollout replayed from the cells' logs."""

    result: RareResult
    reused: bool
