"""Data acquisition over every controller of one experiment (metrics/acquisition.json): each controller's rounds and
check rows as the `acquire` stage wrote them, and the method-level answer — is a method's acquired controller safer
than its behaviour-cloned one at each check cell, and is it no worse at the training condition — over its training
runs (`uqdrive.uq.claims`: sign test and betting interval, valid whatever the runs do).

Replicate r gives one paired difference per cell: η̂1 of its last round common to every replicate of the method
minus round 0's, on the same check seeds. The claims of all methods × cells form one family at α (Bonferroni);
non-inferiority at the training cell reads the lower end of the same claim's mean interval, one more end of an
interval at the claim's level. With two replicates no method claim is decided (the exact sign test needs at least 6
differing runs even at level 0.05); ``differing_runs_needed`` says how many would.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from uqdrive.acquire.acquisition import Acquisition, AcquisitionCheck
from uqdrive.records import read_record, record
from uqdrive.schema import ConfigError
from uqdrive.uq.claims import ClaimResult, MethodClaim, decide_claims
from uqdrive.uq.paired import paired_table


@record
class MethodGain:
    """One method's round ``round`` (the last every replicate reached) against behaviour cloning at ``cell``, over
    its replicates: mean η̂1 before, after and the expert's on the same seeds; ``claim``: "acquired safer" decided;
    ``non_inferior``: at the training cell, whether the mean loss is bounded within ``margin`` ("" elsewhere)."""

    method: str
    cell: str
    round: int
    behaviour_cloned: float
    acquired: float
    expert: float
    claim: ClaimResult
    margin: float
    non_inferior: str  # non-inferior | undecided at the training cell; "" at the others


@record
class AcquisitionSummary:
    """metrics/acquisition.json: ``checks`` is every controller's rows flat (keys method, replicate, round, cell,
    eta1, low, high, expert), ``controllers`` their whole records (rounds, frames and conditions acquired at,
    controller-level verdicts), ``methods`` the method-level answers at family-wise error ``alpha``."""

    experiment: str
    alpha: float
    margin: float
    checks: list[AcquisitionCheck]
    controllers: list[Acquisition]
    methods: list[MethodGain]


def read_acquisitions(folder: str | Path, methods: Sequence[str], replicates: Sequence[int]) -> list[Acquisition]:
    """Every controller's acquisition record (``folder``/<method>-seed<r>.json); a missing one names the stage."""
    return [
        read_record(Acquisition, Path(folder) / f"{m}-seed{r}.json", f"acquire@{m}-{r}")
        for m in methods
        for r in replicates
    ]


def _outcomes(check: AcquisitionCheck) -> np.ndarray:
    return np.array([o == "1" for o in check.outcomes], bool)


def _method_claims(controllers: Sequence[Acquisition], margin: float) -> list[tuple[str, str, int, MethodClaim]]:
    """Per method and check cell, the claim "round K safer than behaviour cloning" over the method's replicates,
    K the last round every replicate of it finished. Only the cells every replicate checked in both rounds: a sweep
    flags each controller's own cells, and a claim over the replicates that happened to be flagged would be a claim
    over a subset the data chose (the others are compared per controller)."""
    claims = []
    for method in dict.fromkeys(a.method for a in controllers):
        own = [a for a in controllers if a.method == method]
        last = min(max(s.round for s in a.rounds) for a in own)
        if last == 0:
            continue
        by = {(a.replicate, c.round, c.cell): c for a in own for c in a.checks}
        common = [c.cell for c in own[0].checks if c.round == 0]
        for cell in (c for c in common if all((a.replicate, k, c) in by for a in own for k in (0, last))):
            tables = {
                a.replicate: paired_table(_outcomes(by[a.replicate, last, cell]), _outcomes(by[a.replicate, 0, cell]))
                for a in own
            }
            name = f"{method} round {last} safer than behaviour cloning at {cell}"
            claims.append((method, cell, last, MethodClaim(name, tables, margin)))
    return claims


def summarise_acquisition(
    experiment: str, controllers: Sequence[Acquisition], alpha: float, margin: float
) -> AcquisitionSummary:
    """Every controller's rows and records, and each method's answer per check cell (one family at ``alpha``)."""
    if not controllers or any(a.experiment != experiment for a in controllers):
        raise ConfigError(f"acquisition of {experiment}: need records of that experiment, got {len(controllers)}")
    planned = _method_claims(controllers, margin)
    decided = decide_claims([c for *_, c in planned], alpha) if planned else []
    methods = []
    for (method, cell, last, _), result in zip(planned, decided):
        rows = [c for a in controllers if a.method == method for c in a.checks if c.cell == cell]
        mean = {k: float(np.mean([c.eta1 for c in rows if c.round == k])) for k in (0, last)}
        expert = float(np.mean([c.expert for c in rows if c.round == 0]))
        training = any(a.training == cell for a in controllers if a.method == method)
        held = (
            "" if not training else "non-inferior" if result.low is not None and result.low > -margin else "undecided"
        )
        methods.append(MethodGain(method, cell, last, mean[0], mean[last], expert, result, margin, held))
    checks = [c for a in controllers for c in a.checks]
    return AcquisitionSummary(experiment, alpha, margin, checks, list(controllers), methods)
