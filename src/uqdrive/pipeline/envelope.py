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

import numpy as np
from omegaconf import DictConfig

from uqdrive.envelope.certify import Decision, certify, decision_order, region_test, threshold_decision
from uqdrive.envelope.partition import Region, partition
from uqdrive.envelope.rollouts import Listed, UniformIn
from uqdrive.envelope.search import search
from uqdrive.pipeline.envelope_config import Envelope, build_envelope
from uqdrive.pipeline.envelope_outputs import envelope_result, log_envelope, write_outputs
from uqdrive.pipeline.records import as_dict
from uqdrive.safety.runner import CellRun, CellRunner, cell_key


def _search_round(envelope: Envelope, runner: CellRunner, cells: list[CellRun]) -> Callable[[np.ndarray], np.ndarray]:
    """Phase one's ``run(points)``: each round is a cell whose rollout i drives at its i-th condition, seeds
    continuing where the last round's ended."""
    env = envelope.settings

    def run(points: np.ndarray) -> np.ndarray:
        job = envelope.job(
            Listed(tuple(map(tuple, points.tolist()))), env.base_seed + sum(len(c.results) for c in cells)
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
        base_seed = env.base_seed + env.search.budget + index * env.region_budget
        job = envelope.job(UniformIn(region.low, region.high), base_seed)
        consumer = {"phase": "certify", "test": dataclasses.asdict(region_test(env, gamma))}
        key = cell_key(job, consumer, env.model_path, __name__)
        log = Path(env.rollout_log) / f"{region.name}.jsonl"
        consume = lambda draws: threshold_decision(env, gamma, draws, cap)  # noqa: E731
        total = env.region_budget if cap is None else min(cap, env.region_budget)
        name = f"envelope {envelope.method} {region.name}"
        cells.append(runner.run(name, job, key, log, base_seed, consume, total, ahead=runner.batch))
        return cells[-1].outcome

    return decide


def run_envelope(cfg: DictConfig) -> dict:
    """Search, partition, certify; writes the result record, the map and its tables, then logs an MLflow run.
    ``reused`` in the result: every rollout was replayed from the cells' logs (nothing simulated)."""
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
    log_envelope(cfg, result, write_outputs(envelope, result, found, results))
    return {**as_dict(result), "reused": all(c.reused for c in [*searched, *certified])}
