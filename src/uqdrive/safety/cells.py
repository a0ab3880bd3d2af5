"""What a cell estimates and from which rollouts: the estimator's settings, the outcomes it pulls in index order
(replayed from the cell's log, reused, or simulated), the model it drives.
The cell's identity, log and executor are the runner's (`uqdrive.safety.runner`)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Literal

import numpy as np

from uqdrive.data.binning import SteeringBins
from uqdrive.models.checkpoint import load_posterior
from uqdrive.models.posterior import Posterior
from uqdrive.safety.executors import Executor
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.rollout_log import RolloutLog
from uqdrive.schema import ConfigError, Count, OpenUnit, Seed, schema
from uqdrive.uq import Estimate
from uqdrive.uq.schemes import CellEstimator, cell_estimator

Scheme = Literal["chernoff", "clopper_pearson", "sequential"]  # the names of `uqdrive.uq.schemes.CELL_ESTIMATORS`


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

    @property
    def method(self) -> CellEstimator:
        """The estimator ``scheme`` names, built once (`uqdrive.uq.schemes`)."""
        return cell_estimator(self.scheme)

    def planned_rollouts(self) -> int:
        """Rollouts the scheme runs (the most it may run, for `sequential`)."""
        return self.method.most(self.theta, self.gamma, self.look_size)

    def fixed_rollouts(self) -> int:
        """Rollouts every cell runs whatever its outcomes (a sequential scheme's earliest stop): a sample whose
        size was fixed in advance, as exact tests on the recorded runs (threshold calibration) need."""
        return self.method.least(self.theta, self.gamma, self.look_size)

    def estimate(self, draw: Callable[[int], np.ndarray]) -> Estimate:
        """η̂ from outcomes ``draw(count)`` pulls in index order, as many as the scheme asks for."""
        return self.method.estimate(draw, self.theta, self.gamma, self.look_size)


class OutcomeStream:
    """Outcomes of rollouts 0, 1, … in index order, as an estimator or a test asks for them (``draw(count)``):
    each rollout comes from the cell's log if an earlier run kept it, else from ``reuse`` (a rollout known to
    be identical, e.g. a warnings-off run in which no warning would fire), else from ``executor``. Every rollout
    not read from the log is appended to it as it finishes, so an interrupted cell resumes where it stopped
    and ends exactly as an uninterrupted one (rollout i always has seed base_seed + i, and consumers read
    outcomes in index order). ``fresh`` counts the rollouts simulated or reused, not replayed from the log.

    ``ahead``: after the first look, simulate up to this many rollouts at a time (never past ``limit``), so a
    sequential test that looks every few rollouts still keeps every worker's lockstep slots full. The test
    reads only the outcomes it asks for, in order, so its decision is the same; the rollouts it did not read
    (``unread``) are logged like the rest, and cost time, not error."""

    def __init__(
        self,
        executor: Executor,
        log: RolloutLog | None = None,
        reuse: Mapping[int, RolloutResult] | None = None,
        progress: Callable[[Iterator[RolloutResult]], Iterator[RolloutResult]] = iter,
        ahead: int = 0,
        limit: int | None = None,
    ):
        self.executor, self.log, self.reuse, self.progress = executor, log, dict(reuse or {}), progress
        self.ahead, self.limit = ahead, limit
        self.kept = log.load() if log is not None else []  # every rollout known, read or not: a prefix of 0, 1, …
        self.results: list[RolloutResult] = []
        self.fresh = 0

    @property
    def unread(self) -> int:
        return len(self.kept) - len(self.results)

    def _run(self, indices: range) -> Iterator[RolloutResult]:
        simulated = self.executor.run([i for i in indices if i not in self.reuse])
        for i in indices:
            yield self.reuse[i] if i in self.reuse else next(simulated)

    def _end(self, needed: int) -> int:
        """Where the next batch of simulation stops: ``needed``, or further after the first look, the batch
        doubling up to ``ahead`` (a test that decides at its second look wastes nothing; a long one soon runs
        full batches)."""
        known = len(self.kept)
        end = max(needed, known + min(known, self.ahead))
        return end if self.limit is None else max(needed, min(end, self.limit))

    def run_to(self, count: int) -> None:
        """Rollouts 0 … ``count`` − 1 known (simulated where missing), whether or not anyone reads them."""
        if len(self.kept) < count:
            for result in self.progress(self._run(range(len(self.kept), count))):
                if self.log is not None:
                    self.log.append(result)
                self.fresh += 1
                self.kept.append(result)

    def __call__(self, count: int) -> np.ndarray:
        start = len(self.results)
        if len(self.kept) < start + count:
            self.run_to(self._end(start + count))
        self.results.extend(self.kept[start : start + count])
        return np.array([r.verdict.safe for r in self.results[start:]], dtype=np.int64)


def cell_posterior(key: str, path: Path, method: str, bins: SteeringBins, trained_by: str) -> Posterior:
    """The cell's model, loaded once up front so a missing, empty or mismatched file fails before any rollout, in
    one line naming the config key and the DVC stage that trains it (``trained_by``)."""
    try:
        return load_posterior(path, expected_method=method, expected_classes=bins)
    except FileNotFoundError:
        raise ConfigError(f"{key}={path} does not exist; train it first: dvc repro {trained_by}") from None
    except ValueError as err:
        raise ConfigError(f"{key}={path}: {str(err).removeprefix(f'{path} ')}; dvc repro {trained_by}") from None
