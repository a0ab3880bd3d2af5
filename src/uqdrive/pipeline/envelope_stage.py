"""The `envelope` stage: one controller's certified operating envelope over two or three continuous condition axes
(`uqdrive.envelope`), e.g. sensor noise × a clear-to-rain weather blend at the training roundabout.

Phase one spends ``envelope.search.budget`` rollouts finding the boundary η1 = τ; its data alone choose the
regions. Phase two certifies each region's η1 on fresh seeds with the sequential threshold test at its share of
γ, so the map's verdicts hold together with probability ≥ 1 − γ. Every round and every region is a cell of the
one cell runner (`uqdrive.safety.runner`): its rollouts are logged and a rerun replays them.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import mlflow
import numpy as np
from omegaconf import DictConfig

from uqdrive.envelope.certify import (
    Decision,
    RegionResult,
    RegionVerdict,
    certify,
    decision_order,
    region_test,
    threshold_decision,
)
from uqdrive.envelope.figure import envelope_figure
from uqdrive.envelope.map_records import EnvelopeResult, EnvelopeRun, envelope_result
from uqdrive.envelope.partition import Region, partition
from uqdrive.envelope.plan import Envelope, build_envelope
from uqdrive.envelope.search import SearchResult, search
from uqdrive.figures import save_figure
from uqdrive.files import write_csv
from uqdrive.records import write_record
from uqdrive.safety.runner import CellRun, CellRunner, cell_key
from uqdrive.tracking import numeric_metrics, stage_run


def _search_round(envelope: Envelope, runner: CellRunner, cells: list[CellRun]) -> Callable[[np.ndarray], np.ndarray]:
    """Phase one's ``run(points)``: each round is a cell whose rollout i drives at its i-th condition, seeds
    continuing where the last round's ended."""
    env = envelope.settings

    def run(points: np.ndarray) -> np.ndarray:
        job = envelope.job(
            envelope.listed(tuple(map(tuple, points.tolist()))), envelope.base_seed + sum(len(c.results) for c in cells)
        )
        name = f"search-{len(cells)}"
        key = cell_key(job, {"phase": "search"}, env.model_path, __name__)
        log = Path(env.rollout_log) / f"{name}.jsonl"
        consume = lambda draws: draws(len(points))  # noqa: E731
        cells.append(
            runner.run(f"envelope {envelope.method} {name}", job, key, log, job.base_seed, consume, len(points))
        )
        return cells[-1].outcome

    return run


def _region_test(
    envelope: Envelope, runner: CellRunner, cells: list[CellRun]
) -> Callable[[int, Region, float, int | None], Decision]:
    """Phase two's ``decide``: region i's cell draws conditions uniformly in it, on seeds after phase one's."""
    env = envelope.settings

    def decide(index: int, region: Region, gamma: float, cap: int | None) -> Decision:
        base_seed = envelope.base_seed + env.search.budget + index * env.region_budget
        job = envelope.job(envelope.uniform_in(region.low, region.high), base_seed)
        consumer = {"phase": "certify", "test": dataclasses.asdict(region_test(env, gamma))}
        key = cell_key(job, consumer, env.model_path, __name__)
        log = Path(env.rollout_log) / f"{region.name}.jsonl"
        consume = lambda draws: threshold_decision(env, gamma, draws, cap)  # noqa: E731
        total = env.region_budget if cap is None else min(cap, env.region_budget)
        name = f"envelope {envelope.method} {region.name}"
        cells.append(runner.run(name, job, key, log, base_seed, consume, total, ahead=runner.batch))
        return cells[-1].outcome

    return decide


def map_figure(envelope: Envelope, result: EnvelopeResult, found: SearchResult, results: list[RegionResult]):
    """Regions by verdict (each a region average of η1), phase one's rollouts as points."""
    env, v, n = envelope.settings, result.verdicts, result.rollouts
    safe, unsafe, undecided = (v[k] for k in RegionVerdict)
    title = (
        f"{envelope.method} {envelope.stage.replicate}: region-average η1 ≥ {env.threshold:g} certified in {safe} "
        f"regions, < {env.threshold:g} in {unsafe}, undecided in {undecided} (all at once w.p. ≥ {1 - env.gamma:g}); "
        f"{n['total']} rollouts"
    )
    return envelope_figure(envelope.space.axes, results, found.points, found.outcomes, title)


def write_tables(plots: Path, result: EnvelopeResult) -> list[Path]:
    """The regions' table and phase one's rollouts (CSV)."""
    rows = [
        {
            "region": r.name,
            **{f"{key}_{end}": b[i] for key, b in r.bounds.items() for i, end in enumerate(("low", "high"))},
            "verdict": r.verdict,
            "rollouts": r.rollouts,
            "safe_rollouts": r.safe_rollouts,
            "gamma": r.gamma,
            "order": r.order,
        }
        for r in result.regions
    ]
    keys = [a.key for a in result.axes]
    conditions = [{**dict(zip(keys, p)), "safe": int(y)} for p, y in zip(result.search.points, result.search.outcomes)]
    return [write_csv(plots / "regions.csv", rows), write_csv(plots / "search.csv", conditions)]


def log(cfg: DictConfig, envelope: Envelope, result: EnvelopeResult, files: list[Path]) -> None:
    """One MLflow run in experiment `envelope`: the stage's section as params, counts and volumes as metrics,
    the map and the tables as artefacts."""
    metrics = {
        **{f"{v}_regions": n for v, n in result.verdicts.items()},
        **{f"{v}_volume": x for v, x in result.volume.items()},
        **{f"{phase}_rollouts": n for phase, n in result.rollouts.items()},
        "grid_rollouts": result.grid.rollouts,
        "search_failures": result.search.failures,
        "seconds": result.seconds,
    }
    run_name = f"{result.method}-seed{result.replicate}"
    with stage_run(envelope.stage.paths.root, "envelope", cfg, run_name=run_name):
        mlflow.log_metrics(numeric_metrics(metrics))
        for path in files:
            mlflow.log_artifact(str(path))


def run_envelope(cfg: DictConfig) -> EnvelopeRun:
    """Search, partition, certify; then the record, the map and its tables, and an MLflow run."""
    envelope = build_envelope(cfg)
    env = envelope.settings
    start = time.perf_counter()
    searched: list[CellRun] = []
    certified: list[CellRun] = []
    with CellRunner.of(envelope.stage.executor, envelope.stage.progress) as runner:
        found = search(_search_round(envelope, runner, searched), envelope.space.dim, env.threshold, env.search)
        model = found.model(env.threshold, env.search.bandwidth)
        regions = partition(model, envelope.space.dim, env.partition)
        order = decision_order(regions, model, env)
        decide = _region_test(envelope, runner, certified)
        results = certify(regions, env.gamma, decide, order, env.certify_budget, env.looks[0])
    unread = sum(c.unread for c in certified)
    result = envelope_result(envelope, found, results, order, time.perf_counter() - start, unread)
    figure = map_figure(envelope, result, found, results)
    plots = Path(env.plots_dir)
    write_record(env.out, result)
    files = [Path(env.out), save_figure(figure, plots / "map.png"), *write_tables(plots, result)]
    log(cfg, envelope, result, files)
    return EnvelopeRun(result, all(c.reused for c in [*searched, *certified]))


def describe(run: EnvelopeRun) -> str:
    """The line the stage prints for a finished map."""
    r = run.result
    v, x, n = r.verdicts, r.volume, r.rollouts
    safe, unsafe, undecided = RegionVerdict.SAFE, RegionVerdict.UNSAFE, RegionVerdict.UNDECIDED
    return (
        f"envelope {r.method} seed{r.replicate}: {len(r.regions)} regions, safe {v[safe]} ({x[safe]:.0%} of the box), "
        f"unsafe {v[unsafe]} ({x[unsafe]:.0%}), undecided {v[undecided]} ({x[undecided]:.0%}); {n['total']} rollouts "
        f"({n['search']} search, {n['certify']} certify, {n['unread']} run ahead unread; a grid of the finest "
        f"regions with per-cell intervals needs {r.grid.rollouts}) in {r.seconds:.0f} s"
        f"{' (reused: every rollout replayed)' if run.reused else ''}"
    )
