"""Interrupt-safe cells: an interrupted cell resumes from its rollout log and ends exactly as an uninterrupted run."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pytest

from uqdrive.safety import runner as runner_module
from uqdrive.safety.cells import EstimatorSettings, OutcomeStream
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.rollout_log import RolloutLog
from uqdrive.safety.safe_sets import PathVerdict
from uqdrive.schema import ConfigError, validate

BASE_SEED = 1000


def fake_rollout(seed: int) -> RolloutResult:
    """A rollout whose every field, arrays included, follows from its seed (as a real one does)."""
    rng = np.random.default_rng(seed)
    steps = int(rng.integers(3, 9))
    safe = bool(rng.random() < 0.93)
    return RolloutResult(
        seed=seed,
        termination="" if safe else "collision",
        verdict=PathVerdict(
            safe=safe,
            collision=not safe,
            off_road=False,
            left_corridor=not safe,
            reached_goal=safe,
            corridor_use=float(rng.random()) * (2 if not safe else 1),
            margin=float(rng.random()) * (1 if safe else -1),
        ),
        mean_abs_lateral_deviation=float(rng.random()),
        mean_eta2=float(rng.random()),
        mean_mutual_information=float("nan"),
        steps=steps,
        x=rng.normal(size=steps + 1),
        y=rng.normal(size=steps + 1).astype(np.float32),
        eta2=rng.random(steps),
        mutual_information=np.full(steps, np.nan),
        warning=rng.integers(-1, 3, steps).astype(np.int8),
        command_speed=rng.random(steps),
    )


class FakeExecutor:
    """Runs rollouts ``indices`` in order; raises KeyboardInterrupt once ``interrupt_after`` results were given."""

    def __init__(self, interrupt_after: int | None = None):
        self.interrupt_after, self.ran = interrupt_after, []

    def run(self, indices: Sequence[int]) -> Iterator[RolloutResult]:
        for i in indices:
            if self.interrupt_after is not None and len(self.ran) >= self.interrupt_after:
                raise KeyboardInterrupt
            self.ran.append(i)
            yield fake_rollout(BASE_SEED + i)

    def close(self) -> None:
        """Nothing to release."""


def estimate_safety(executor, settings: EstimatorSettings, log: RolloutLog | None = None):
    """What `CellRunner.run` does with a cell's executor and log: the estimator reads an `OutcomeStream`."""
    stream = OutcomeStream(executor, log)
    return settings.estimate(stream), stream.results


def same(a: RolloutResult, b: RolloutResult) -> bool:
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            if x.dtype != y.dtype or not np.array_equal(x, y, equal_nan=True):
                return False
        elif x != y and not (x != x and y != y):  # NaN equals NaN here
            return False
    return True


@pytest.mark.parametrize(("scheme", "interrupt_after"), [("sequential", 13), ("sequential", 22), ("chernoff", 7)])
def test_interrupted_cell_resumes_to_the_uninterrupted_result(
    tmp_path: Path, scheme: str, interrupt_after: int
) -> None:
    settings = EstimatorSettings(scheme, 0.1, 0.05, BASE_SEED, look_size=4)
    reference, ref_results = estimate_safety(FakeExecutor(), settings)
    assert len(ref_results) > interrupt_after

    log = RolloutLog(tmp_path / "cell.jsonl", "hash-a", BASE_SEED)
    with pytest.raises(KeyboardInterrupt):
        estimate_safety(FakeExecutor(interrupt_after), settings, log=log)
    resumed_executor = FakeExecutor()
    estimate, results = estimate_safety(resumed_executor, settings, log=log)

    assert estimate == reference
    assert len(results) == len(ref_results) and all(same(a, b) for a, b in zip(results, ref_results))
    assert resumed_executor.ran == list(range(interrupt_after, len(ref_results)))  # nothing kept was rerun


class BatchRecorder(FakeExecutor):
    """A `FakeExecutor` that also records each request's indices."""

    def __init__(self):
        super().__init__()
        self.requests: list[list[int]] = []

    def run(self, indices: Sequence[int]) -> Iterator[RolloutResult]:
        self.requests.append(list(indices))
        return super().run(indices)


@pytest.mark.parametrize("theta", [0.1, 0.05])
def test_running_ahead_fills_batches_and_changes_no_estimate(tmp_path: Path, theta: float) -> None:
    settings = EstimatorSettings("sequential", theta, 0.05, BASE_SEED, look_size=4)
    reference, ref_results = estimate_safety(FakeExecutor(), settings)
    limit = settings.planned_rollouts()

    executor, log = BatchRecorder(), RolloutLog(tmp_path / "cell.jsonl", "hash-a", BASE_SEED)
    draws = OutcomeStream(executor, log, ahead=16, limit=limit)
    assert settings.estimate(draws) == reference
    assert len(draws.results) == len(ref_results) and all(same(a, b) for a, b in zip(draws.results, ref_results))
    first, *rest = executor.requests
    assert first == list(range(len(first))) and rest  # the first look runs only what it asks for
    for before, request in zip(executor.requests, rest):  # then batches doubling up to 16, never past the limit
        assert request[0] == before[-1] + 1
        assert len(request) >= min(request[0], 16) or request[-1] == limit - 1
    assert 16 in map(len, executor.requests) and max(executor.ran) < limit
    assert draws.unread == len(draws.kept) - len(ref_results) < 16

    replay = BatchRecorder()  # the unread rollouts were logged too: a rerun simulates nothing
    again = OutcomeStream(replay, RolloutLog(tmp_path / "cell.jsonl", "hash-a", BASE_SEED), ahead=16, limit=limit)
    assert settings.estimate(again) == reference and replay.ran == [] and again.fresh == 0


@pytest.mark.parametrize("scheme", ["sequential", "clopper_pearson"])
def test_a_sequential_cell_runs_ahead_to_fill_the_workers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, scheme: str
) -> None:
    settings = EstimatorSettings(scheme, 0.1, 0.05, BASE_SEED, look_size=4)
    reference, ref_results = estimate_safety(FakeExecutor(), settings)
    executor = BatchRecorder()
    monkeypatch.setattr(runner_module, "make_executor", lambda *args, **kwargs: executor)
    with runner_module.CellRunner("ray", 2, progress=False) as runner:  # the executor is the fake: nothing starts
        run = runner.estimate("cell", None, settings, "hash-a", tmp_path / "cell.jsonl")
    assert run.outcome == reference
    assert len(run.results) == len(ref_results) and all(same(a, b) for a, b in zip(run.results, ref_results))
    assert run.unread == len(executor.ran) - len(ref_results)
    if scheme == "sequential":  # looks of 4 rollouts, run in batches that fill both workers' lockstep slots
        assert max(map(len, executor.requests)) == runner.batch and run.unread > 0
    else:  # a fixed-n scheme asks for all its rollouts at once
        assert executor.requests == [list(range(settings.planned_rollouts()))] and run.unread == 0


def test_running_ahead_stops_at_the_limit() -> None:
    executor = BatchRecorder()
    draws = OutcomeStream(executor, ahead=16, limit=10)
    for count in (4, 4, 2):
        draws(count)
    assert executor.requests == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9]] and draws.unread == 0


def test_a_cut_line_is_dropped_and_another_config_starts_afresh(tmp_path: Path) -> None:
    settings = EstimatorSettings("sequential", 0.25, 0.05, BASE_SEED, look_size=4)
    path = tmp_path / "cell.jsonl"
    with pytest.raises(KeyboardInterrupt):
        estimate_safety(FakeExecutor(9), settings, log=RolloutLog(path, "hash-a", BASE_SEED))
    with path.open("a") as f:
        f.write('{"seed": 1009, "safe": tr')  # an interrupt in the middle of a write
    assert [r.seed for r in RolloutLog(path, "hash-a", BASE_SEED).load()] == list(range(1000, 1009))
    assert path.read_text().count("\n") == 10  # header + 9 complete lines: appends continue cleanly

    executor = FakeExecutor()
    estimate_safety(executor, settings, log=RolloutLog(path, "hash-b", BASE_SEED))  # changed config
    assert executor.ran[0] == 0


def test_look_size_below_one_is_rejected() -> None:
    with pytest.raises(ConfigError, match=r"^avoid.look_size=0: input should be greater than or equal to 1$"):
        validate(EstimatorSettings, {"scheme": "sequential", "look_size": 0}, "avoid")
