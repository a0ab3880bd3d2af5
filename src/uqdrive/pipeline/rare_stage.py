"""The `rare` stage: "η1 ≥ target over the operating domain" for one controller, refuted by importance sampling
with a bound valid at any stopping time and, if asked, certified by the exact sequential test (`uqdrive.uq.rare`,
docs/rare.md). The domain is a density over the envelope's condition space (`uqdrive.envelope.domain`); the
world, controller and executor are the envelope stage's. Every round of the refutation and every look of the
certification is a cell of the one cell runner (`uqdrive.safety.runner`): logged, and replayed on a rerun (the
conditions come from ``rare.seed``'s stream, so a rerun asks for the same cells).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import mlflow
import numpy as np
from omegaconf import DictConfig

from uqdrive.envelope.domain import Domain, RareSection
from uqdrive.envelope.plan import Envelope, build_envelope
from uqdrive.records import write_record
from uqdrive.safety.runner import CellRun, CellRunner, cell_key
from uqdrive.schema import validate
from uqdrive.tracking import numeric_metrics, stage_run
from uqdrive.uq.rare import FailureEstimate, certify, failure_estimate, failure_lower_bound, refute


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


def _cell(envelope: Envelope, section: RareSection, runner: CellRunner, cells: list[CellRun], points, base: int):
    """One cell: rollout i at the i-th point, on seed base + i; its 0/1 outcomes (1: safe) and margins."""
    listed = envelope.listed(tuple(map(tuple, np.asarray(points, float).tolist())))
    job = envelope.job(listed, base)
    name = f"cell-{len(cells)}"
    key = cell_key(job, {"phase": "rare"}, envelope.settings.model_path, __name__)
    log = Path(section.rollout_log) / f"{name}.jsonl"
    count = len(listed.points)
    cells.append(runner.run(f"rare {envelope.method} {name}", job, key, log, base, lambda d: d(count), count))
    safe = np.asarray(cells[-1].outcome, int)
    margins = np.array([r.verdict.margin for r in cells[-1].results], float)
    margins = np.where(np.isnan(margins), np.where(safe == 1, 1.0, -1.0), margins)  # no lane rule: the outcome
    return safe, np.where(safe == 1, np.maximum(margins, 0.0), np.minimum(margins, 0.0))


def run_rare(cfg: DictConfig) -> RareRun:
    """Validate, refute (and certify if asked), then the record and an MLflow run."""
    section = validate(RareSection, cfg.rare, "rare")  # first: a bad rare value is named before the model is read
    envelope = build_envelope(cfg)
    domain = Domain.over(envelope.space, dict(section.shapes or {}))
    rng, base = np.random.default_rng(section.seed), envelope.stage.rollout_seeds(section.base_seed)
    start, cells = time.perf_counter(), []
    with CellRunner.of(envelope.stage.executor, envelope.stage.progress) as runner:

        def world(points: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            safe, margins = _cell(envelope, section, runner, cells, points[0], int(seeds[0, 0]))
            return (safe == 0)[None], margins[None]

        found = refute(world, domain.nominal, section, rng, seed=base, names=domain.space.names)
        certified, certify_rollouts = "not_run", 0
        if section.certify:
            drawn = [base + section.refute_budget]

            def draw(m: int) -> np.ndarray:
                safe, _ = _cell(envelope, section, runner, cells, domain.sample(rng, m), drawn[0])
                drawn[0] += m
                return safe

            decision = certify(draw, section)
            certified, certify_rollouts = decision.decision or "undecided", decision.n
    n = int(found.rollouts[0])
    records = [{"seed": r.seed, **domain.space.values(r.point), "weight": r.weight} for r in found.records]
    result = RareResult(
        envelope.method,
        envelope.stage.seed,
        section.target,
        section.gamma,
        {
            a.key: [a.low, a.high, *map(float, (domain.nominal.a[i], domain.nominal.b[i]))]
            for i, a in enumerate(domain.space.axes)
        },
        bool(found.refuted[0]),
        n,
        int(found.failures[0]),
        failure_lower_bound(found.observations[0, :n], section.gamma),
        failure_estimate(found.observations[0, :n], section.defensive, section.gamma),
        certified,
        certify_rollouts,
        records,
        time.perf_counter() - start,
    )
    write_record(section.out, result)
    _log(cfg, result, Path(section.out))
    return RareRun(result, all(c.reused for c in cells))


def _log(cfg: DictConfig, result: RareResult, out: Path) -> None:
    """One MLflow run in experiment `rare`: the config as params, the verdicts and counts as metrics."""
    metrics = {
        "refuted": int(result.refuted),
        "refute_rollouts": result.refute_rollouts,
        "failures": result.failures,
        "failure_lower_bound": result.lower_bound,
        "failure_estimate": result.estimate.estimate,
        "failure_interval_high": result.estimate.interval[1],
        "certified": {"above": 1, "below": -1}.get(result.certified, 0),
        "certify_rollouts": result.certify_rollouts,
        "seconds": result.seconds,
    }
    with stage_run(cfg.paths.root, "rare", cfg, run_name=f"{result.method}-seed{result.replicate}"):
        mlflow.log_metrics(numeric_metrics(metrics))
        mlflow.log_artifact(str(out))


def describe(run: RareRun) -> str:
    """The line the stage prints."""
    r = run.result
    verdict = f"refuted: η1 < {r.target:g}" if r.refuted else f"not refuted (η1 < {r.target:g} not shown)"
    return (
        f"rare {r.method} seed{r.replicate}: {verdict} after {r.refute_rollouts} rollouts, {r.failures} failures, "
        f"failure probability over the domain >= {r.lower_bound:.3g} (error <= {r.gamma:g}), estimated "
        f"{_estimate(r.estimate, r.gamma)}; certification "
        f"{r.certified} after {r.certify_rollouts} rollouts in {r.seconds:.0f} s"
        f"{' (reused: every rollout replayed)' if run.reused else ''}"
    )


def _estimate(e: FailureEstimate, gamma: float) -> str:
    """p̂ with its intervals, the assumption named where one is needed."""
    text = f"{e.estimate:.3g} ({1 - gamma:g}: [{e.interval[0]:.3g}, {e.interval[1]:.3g}] without assumption"
    if e.if_dominant is not None:
        low, high = e.if_dominant
        text += f"; [{low:.3g}, {high:.3g}] if the proposal dominated the domain's density where the car failed"
    return text + ")"
