"""Re-drive one rollout of a cell exactly, watching it: the frame the network saw at every step, the world's own
picture (a Gymnasium env's render, where it has one) and the commands.

A rollout is named only by its seed (``base_seed`` + i): its start, weather, sensor noise and posterior draws all
come from it, in any process and any lockstep slot (`uqdrive.safety.executors`), so driving it alone on one thread
gives the cell's result again. `check_against` proves it did: same outcome, termination, step count and path (bit
for bit, by digest) as the cell recorded.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import torch

from uqdrive.network_input import preprocess_frame
from uqdrive.policy.interface import Command, LockstepPolicy
from uqdrive.policy.slots import in_lockstep
from uqdrive.safety.executors import RolloutJob, job_env
from uqdrive.safety.failures import RolloutFailure, path_digest
from uqdrive.safety.rollout import RolloutResult, run_rollouts
from uqdrive.sim.world import World


@dataclasses.dataclass(frozen=True)
class Watched:
    """A re-driven rollout and what was seen on the way, one entry per control step: ``frames`` (the grey 64x48 the
    network read; None where the policy reads no camera), ``views`` (the env's own render, None where it has none),
    ``steer`` (the commanded steering)."""

    index: int
    result: RolloutResult
    frames: list[np.ndarray | None]
    views: list[np.ndarray | None]
    steer: np.ndarray


class _Watcher(LockstepPolicy):
    """A `Policy` that passes every decision to ``policy`` and keeps what it was shown and what it commanded."""

    def __init__(self, policy: LockstepPolicy, world: World):
        self.policy, self.world = policy, world
        self.needs_camera = policy.needs_camera
        self.frames: list[np.ndarray | None] = []
        self.views: list[np.ndarray | None] = []
        self.steer: list[float] = []

    def reset(self, seed: int, slot: int = 0, world: World | None = None) -> None:
        self.policy.reset(seed, slot, world)

    def act_batch(
        self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]
    ) -> list[Command]:
        frame = frames[0]
        self.frames.append(None if frame is None else preprocess_frame(frame))
        self.views.append(self.world.view())
        commands = self.policy.act_batch(slots, frames, infos)
        self.steer.append(float(commands[0].steer))
        return commands


def _world(job: RolloutJob, index: int) -> World:
    """A fresh world for rollout ``index``, drawing its own picture where it can (`World.watch`: `check_against`
    proves the path unchanged)."""
    world = job_env(job, index)
    world.watch()
    return world


class Redriver:
    """Re-drives rollouts of one job on one policy and world, built once (a cell's clips share them, as a worker's
    rollouts do), on one torch thread as a worker drives them. A context manager."""

    def __init__(self, job: RolloutJob):
        self.job, self.world = job, None
        self.threads = torch.get_num_threads()
        torch.set_num_threads(1)
        self.policy: LockstepPolicy = in_lockstep(job.policy.build(job.control_hz))

    def drive(self, index: int) -> Watched:
        """Rollout ``index`` (seed base_seed + index), watched."""
        job = self.job
        self.world = self.world or _world(job, index)
        watcher = _Watcher(self.policy, self.world)
        (result,) = run_rollouts([self.world], watcher, [job.base_seed + index], [job.condition(index)], job.half_width)
        return Watched(index, result, watcher.frames, watcher.views, np.array(watcher.steer, float))

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
        torch.set_num_threads(self.threads)

    def __enter__(self) -> Redriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def redrive(job: RolloutJob, index: int) -> Watched:
    """Rollout ``index`` of ``job`` driven alone (`Redriver`)."""
    with Redriver(job) as driver:
        return driver.drive(index)


def check_against(watched: Watched, safe: bool, margin: float | None, failure: RolloutFailure | None) -> list[str]:
    """How the re-driven rollout differs from what the cell recorded for it (empty: it is the same): its outcome
    and margin, and where it failed, the termination, step count and path digest."""
    result, differences = watched.result, []
    if result.verdict.safe != safe:
        differences.append(
            f"outcome {'safe' if result.verdict.safe else 'unsafe'}, recorded {'safe' if safe else 'unsafe'}"
        )
    replayed_margin = None if math.isnan(result.verdict.margin) else round(float(result.verdict.margin), 6)
    if replayed_margin != margin:
        differences.append(f"margin {replayed_margin}, recorded {margin}")
    if failure is not None:
        for name, now, then in (
            ("termination", result.termination, failure.termination),
            ("steps", result.steps, failure.steps),
            ("path sha256", path_digest(result.x, result.y)[:12], failure.path_sha256[:12]),
        ):
            if now != then:
                differences.append(f"{name} {now}, recorded {then}")
    return differences
