"""Re-decide a findings file with the current procedures from what it records, without rerunning a rollout: each
comparison's per-replicate counts (runs where only A, only B was safe) and each method claim's per-replicate
differences. How the committed study was re-decided when the procedures changed (`uqdrive redecide`).

A claim needs only its per-replicate differences, so its verdict is the findings stage's exactly. A comparison's
interval reads each replicate's runs in seed order, which a file does not hold: each replicate's runs are laid out
in an order drawn from a seeded generator. Runs are i.i.d. within a replicate, so any order drawn independently of
the outcomes has the seed order's law and the interval keeps its guarantee; its ends can differ slightly from
those the stage computes from the cells.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from uqdrive.analysis.comparisons import Findings, decide
from uqdrive.analysis.method_claims import ClaimRecord, claim_record
from uqdrive.records import write_record
from uqdrive.uq.claims import MethodClaim, ScoreClaim, decide_claims
from uqdrive.uq.family import Comparison
from uqdrive.uq.paired import PairedTable
from uqdrive.uq.runs_needed import SIMS

MARGIN_FAMILY = "margin"


def _laid_out(a_only: int, b_only: int, runs: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A replicate's paired outcomes with these counts, in an order drawn by ``rng`` (concordant runs count both
    safe: the comparison reads only where the two differ)."""
    a = np.array([True] * a_only + [False] * b_only + [True] * (runs - a_only - b_only))
    b = np.array([False] * a_only + [True] * b_only + [True] * (runs - a_only - b_only))
    order = rng.permutation(runs)
    return a[order], b[order]


def _comparisons(raw: list[dict], rng: np.random.Generator) -> list[tuple]:
    family = []
    for f in raw:
        replicates = sorted(f["a_only"], key=int)
        runs = f["runs"] if "runs" in f else f["pairs"] // len(replicates)
        outcomes = {int(r): _laid_out(f["a_only"][r], f["b_only"][r], runs, rng) for r in replicates}
        family.append((f["experiment"], f["kind"], f["topic"], f["a"], f["b"], Comparison(f["name"], outcomes)))
    return family


def check_claim(raw: dict) -> None:
    """A recorded claim names one replicate per difference and per side's rate, each once (ValueError, one line)."""
    replicates, counts = raw["replicates"], {k: len(raw[k]) for k in ("per_replicate", "a_rates", "b_rates")}
    if len(set(replicates)) != len(replicates) or any(n != len(replicates) for n in counts.values()):
        sides = ", ".join(f"{k} {n}" for k, n in counts.items())
        raise ValueError(f"claim {raw['name']!r}: replicates {replicates} but {sides} values: the sides do not pair")


def _claims(raw: list[dict], alpha: float, margin: float, sims: int) -> list[ClaimRecord]:
    for c in raw:
        check_claim(c)
    records = []
    for family in dict.fromkeys(c["family"] for c in raw):
        members = [c for c in raw if c["family"] == family]
        on_margins = family == MARGIN_FAMILY
        claims = [_claim(c, margin, on_margins) for c in members]
        for c, decided in zip(members, decide_claims(claims, alpha, sims if family == "paper" else 0)):
            what = (c["experiment"], c["a"], c["b"], c["paper"])
            records.append(claim_record(family, what, decided, (c["a_rates"], c["b_rates"]), c["pairs"], on_margins))
    return records


def _claim(raw: dict, margin: float, on_margins: bool) -> MethodClaim | ScoreClaim:
    """A recorded claim from its per-replicate differences (η1's as tables of the same effect)."""
    differences = dict(zip(raw["replicates"], raw["per_replicate"]))
    if on_margins:
        # each replicate's mean difference, repeated over its runs: the mean (all the sign test reads) and n kept
        return ScoreClaim(raw["name"], {r: np.full(raw["pairs"], d) for r, d in differences.items()}, margin)
    runs = raw["pairs"]
    tables = {r: PairedTable(runs, max(0, round(d * runs)), max(0, -round(d * runs))) for r, d in differences.items()}
    return MethodClaim(raw["name"], tables, margin)


def redecide(raw: dict, seed: int = 0, sims: int = SIMS) -> Findings:
    """The findings of a file's recorded counts and differences under the current procedures (``sims``: simulated
    studies per run count for the paper claims' runs needed)."""
    alpha, margin = float(raw["alpha"]), float(raw.get("margin", 0.1))
    claims = _claims(raw.get("claims", []), alpha, margin, sims)  # checked before any comparison is decided
    findings = decide(_comparisons(raw["findings"], np.random.default_rng(seed)), alpha)
    return dataclasses.replace(findings, margin=margin, claims=claims)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="uqdrive redecide",
        description="Re-decide a findings file's recorded comparisons and claims with the current procedures.",
    )
    parser.add_argument("path", type=Path, help="a findings file (metrics/findings.json or docs/study/findings.json)")
    parser.add_argument("--out", type=Path, help="where to write the re-decided file (default: over the input)")
    parser.add_argument("--seed", type=int, default=0, help="the seed of the runs' drawn order (default 0)")
    parser.add_argument("--sims", type=int, default=SIMS, help=f"simulations for the runs needed (default {SIMS})")
    args = parser.parse_args(argv)
    try:
        findings = redecide(json.loads(args.path.read_text()), args.seed, args.sims)
    except ValueError as error:
        print(f"error: {args.path}: {error}")
        return 2
    write_record(args.out or args.path, findings)
    print(
        f"{findings.supported} of {findings.comparisons} comparisons supported; claims decided for the mean: "
        f"{sum(c.result.verdict != 'undecided' for c in findings.claims)} of {len(findings.claims)}, for q: "
        f"{sum(c.result.sign_verdict != 'undecided' for c in findings.claims)}"
    )
    return 0
