"""Parallel rollouts of an env as it is: two worker processes, the one given the first seeds made the slower, so
the other finishes first; the executor still hands the outcomes over in seed order, equal to one worker's and to a
plain Gymnasium loop's — so a sequential test reading them reads what it would have read alone."""

from __future__ import annotations

import native_kit
import pytest
from user_policy_kit import write_yaml

from uqdrive.policy.policy_files import load_policy
from uqdrive.safety.executors import RolloutJob, job_world, make_executor
from uqdrive.schema import validate
from uqdrive.sim import CameraConfig, VehicleConfig
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import GymWorldConfig


def outcomes(job: RolloutJob, workers: int) -> list:
    executor = make_executor("process", job, workers, lockstep=1)
    try:
        return list(executor.run(range(4)))
    finally:
        executor.close()


@pytest.mark.slow  # starts a pool of two worker processes
def test_outcomes_come_in_seed_order_whichever_worker_finishes_first(tmp_path):
    finished = tmp_path / "finished"
    finished.mkdir()
    world = validate(GymWorldConfig, {
        "name": "slow", "env_id": f"native_kit:{native_kit.SLOW}", "hooks": "native", "safe_if": {},
        "unsafe_if": ["fell"], "horizon_steps": 20,
        "env_kwargs": {"delay": 0.05, "slow_below": 2, "log_dir": str(finished)},
    })  # fmt: skip
    spec = load_policy(write_yaml(tmp_path / "a.yaml", "policy:\n  _target_: native_kit.toward_centre\n"), native=True)
    where = Condition(world, None)
    job = RolloutJob(spec, where, 0, **job_world(where, CameraConfig(), VehicleConfig(), 15.0, 1.0))
    parallel = outcomes(job, 2)
    ended = {int(p.name): float(p.read_text()) for p in finished.iterdir()}
    assert ended[2] < ended[3] < ended[0] < ended[1]  # the second worker's chunk (seeds 2, 3) ended first
    assert [r.seed for r in parallel] == [0, 1, 2, 3]
    alone = outcomes(job, 1)
    assert [(r.seed, r.verdict.safe, r.termination, r.steps) for r in parallel] == [
        (r.seed, r.verdict.safe, r.termination, r.steps) for r in alone
    ]
    plain = native_kit.plain_outcomes(native_kit.WALK, native_kit.toward_centre, range(4), lambda o, i, t: i["fell"])
    assert "".join("1" if r.verdict.safe else "0" for r in parallel) == plain
