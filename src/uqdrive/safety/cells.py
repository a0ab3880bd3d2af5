"""One sweep cell (method × scenario × weather × noise): its validated settings, its identity, its estimate.

A cell's result is keyed by a hash of everything that decides it (the model file's bytes,
the world, the estimator, the seeds) and nothing that does not (worker count, backend,
output paths), so an interrupted sweep run again reuses every finished cell.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from uqdrive.data.binning import SteeringBins
from uqdrive.models.checkpoint import load_posterior
from uqdrive.models.posterior import Posterior
from uqdrive.safety.executors import Executor
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.rollout_log import RolloutLog
from uqdrive.schema import Count, OpenUnit, Seed, schema
from uqdrive.uq import Estimate, chernoff, chernoff_n, clopper_pearson, clopper_pearson_n, sequential, sequential_scheme

Scheme = Literal["chernoff", "clopper_pearson", "sequential"]
_PLANNED: dict[str, tuple[Callable[[float, float], int], Callable[[int, int, float, float], Estimate]]] = {
    "chernoff": (chernoff_n, chernoff),
    "clopper_pearson": (clopper_pearson_n, clopper_pearson),
}


@schema(frozen=True)
class EstimatorSettings:
    """How η1 is estimated: scheme and (θ, γ) with P(|η̂1 − η1| > θ) ≤ γ; rollout i uses seed base_seed + i.

    ``look_size``: `sequential` looks after every look_size rollouts (a batch the workers run in
    parallel); 4 costs ≤ 1 rollout on average against looking after each one at θ = γ = 0.05.
    """

    scheme: Scheme = "chernoff"
    theta: OpenUnit = 0.05
    gamma: OpenUnit = 0.05
    base_seed: Seed = 0
    look_size: Count = 4

    @property
    def estimator(self) -> EstimatorSettings:
        """These settings alone (a stage's config section that extends them holds more)."""
        return EstimatorSettings(self.scheme, self.theta, self.gamma, self.base_seed, self.look_size)

    def planned_rollouts(self) -> int:
        """Rollouts the scheme runs (the most it may run, for `sequential`)."""
        if self.scheme == "sequential":
            return sequential_scheme(self.theta, self.gamma, self.look_size).max_n
        return _PLANNED[self.scheme][0](self.theta, self.gamma)


def estimate_safety(
    executor: Executor,
    settings: EstimatorSettings,
    progress: Callable[[Iterator[RolloutResult]], Iterator[RolloutResult]] = iter,
    log: RolloutLog | None = None,
) -> tuple[Estimate, list[RolloutResult]]:
    """Run rollouts 0, 1, … as the scheme asks for them and estimate η1 = P(path in the safe set).

    With ``log``, each finished rollout is kept as it finishes and the rollouts an interrupted
    run already kept are reused, not rerun: the estimate and the returned rollouts are exactly
    those of an uninterrupted run (the scheme consumes outcomes in index order).
    """
    kept = log.load() if log is not None else []
    results: list[RolloutResult] = []

    def fresh(indices: range) -> Iterator[RolloutResult]:
        for result in progress(executor.run(indices)):
            if log is not None:
                log.append(result)
            yield result

    def draw(count: int) -> np.ndarray:
        start = len(results)
        reused = kept[start : start + count]
        results.extend(reused)
        results.extend(fresh(range(start + len(reused), start + count)) if len(reused) < count else ())
        return np.array([r.safe for r in results[start:]], dtype=np.int64)

    if settings.scheme == "sequential":
        return sequential(draw, settings.theta, settings.gamma, settings.look_size), results
    n = settings.planned_rollouts()
    k = int(draw(n).sum())
    return _PLANNED[settings.scheme][1](k, n, settings.theta, settings.gamma), results


def cell_posterior(key: str, path: Path, method: str, bins: SteeringBins) -> Posterior:
    """The cell's model, loaded once up front so a missing or mismatched file fails before any rollout."""
    if not path.exists():
        raise FileNotFoundError(f"{key}={path} does not exist; train it first (dvc repro train_mcd / train@{method})")
    return load_posterior(path, expected_method=method, expected_classes=bins)


def file_digest(path: str | Path) -> str:
    """sha256 of a file's bytes: a retrained model is a new cell even at the same path."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def cell_hash(identity: dict) -> str:
    """Stable hash of a JSON-able description of everything that decides a cell's result."""
    return hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()[:16]


def reusable_result(path: str | Path, key: str) -> dict | None:
    """The finished result at ``path`` if it was computed for the cell with hash ``key``."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        result = json.loads(path.read_text())
    except json.JSONDecodeError:
        return None
    return result if isinstance(result, dict) and result.get("config_hash") == key else None


def rates(results: Sequence[RolloutResult]) -> dict[str, float]:
    """Per-cell summaries beside η̂1: how paths failed and how well they tracked the route."""

    def mean(values: list[float]) -> float:
        finite = [v for v in values if not math.isnan(v)]
        return float(np.mean(finite)) if finite else float("nan")

    return {
        "collision_rate": mean([r.collision for r in results]),
        "off_road_rate": mean([r.off_road for r in results]),
        "left_corridor_rate": mean([r.left_corridor for r in results]),
        "reached_goal_rate": mean([r.reached_goal for r in results]),
        "max_corridor_use": max([r.corridor_use for r in results if not math.isnan(r.corridor_use)], default=math.nan),
        "mean_corridor_use": mean([r.corridor_use for r in results]),
        "mean_lateral_deviation": mean([r.mean_abs_lateral_deviation for r in results]),
        "mean_eta2": mean([r.mean_eta2 for r in results]),
        "mean_mutual_information": mean([r.mean_mutual_information for r in results]),
    }
