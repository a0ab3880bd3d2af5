"""Expert episodes: the expert drives a scenario and every camera frame is recorded with its steering label — the
data the controllers learn from (stage `collect`) and are evaluated on (stage `heldout`). The expert is the
autopilot in the pybullet world, a Gymnasium world's own (`GymWorld.expert_command`) in that world."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from uqdrive.sim.autopilot import Autopilot, SteeringPerturbation
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import SimConfig
from uqdrive.sim.env import DrivingEnv
from uqdrive.sim.gym_world import GymWorld

RECORDED = ("t", "x", "y", "yaw", "speed", "lateral_deviation")  # info keys recorded with every frame


def record_episode(
    env: DrivingEnv, sim: SimConfig, seed: int, where: Condition, encode: Callable[[np.ndarray], object]
) -> tuple[dict[str, list], str, list[np.ndarray]]:
    """Drive one episode; each row pairs the frame seen at step k (``encode``d) with the autopilot's label for it.
    Returns the columns, the termination and the raw frames."""
    rows: dict[str, list] = {key: [] for key in (*RECORDED, "step", "steering", "applied_steering", "image")}
    frames: list[np.ndarray] = []
    obs = env.reset(seed, where)
    autopilot = Autopilot(env.route, env.vehicle_config, sim.autopilot, env.control_hz, seed=seed)
    info = env.last_info
    step = 0
    while not env.done:
        action = autopilot.act(info)
        for key in RECORDED:
            rows[key].append(info[key])
        rows["step"].append(step)
        rows["steering"].append(action.label)
        rows["applied_steering"].append(action.steer)
        rows["image"].append(encode(obs))
        frames.append(obs)
        obs, info = env.step(action.steer, action.speed)
        step += 1
    return rows, info["termination"], frames


def record_expert_episode(
    world: GymWorld, sim: SimConfig, seed: int, where: Condition, encode: Callable[[np.ndarray], object]
) -> tuple[dict[str, list], str, list[np.ndarray]]:
    """`record_episode` in a Gymnasium world: its own expert labels each frame, and its steering is pushed off now
    and then as the autopilot's is (``sim.autopilot``'s perturbations, seeded by the episode), so the data also
    shows how to come back; the commanded speed is the expert's."""
    rows: dict[str, list] = {key: [] for key in (*RECORDED, "step", "steering", "applied_steering", "image")}
    frames: list[np.ndarray] = []
    obs = world.reset(seed, where)
    perturbation = SteeringPerturbation(sim.autopilot, world.control_hz, seed)
    info = world.last_info
    step = 0
    while not world.done:
        label, speed = world.expert_command()
        steer, _ = perturbation.apply(label)
        for key in RECORDED:
            rows[key].append(info[key])
        rows["step"].append(step)
        rows["steering"].append(label)
        rows["applied_steering"].append(steer)
        rows["image"].append(encode(obs))
        frames.append(obs)
        obs, info = world.step(steer, speed)
        step += 1
    return rows, info["termination"], frames


@dataclasses.dataclass(frozen=True)
class EpisodeJob:
    """Autopilot episodes at one condition, for `uqdrive.parallel.ProcessPool`: episode e uses seed ``base_seed + e``;
    ``encode`` turns a frame into what the table stores (a module-level function, so the job pickles)."""

    sim: SimConfig
    where: Condition
    base_seed: int
    mosaic_columns: int
    encode: Callable[[np.ndarray], object]

    def worker(self) -> EpisodeWorker:
        return EpisodeWorker(self)


class EpisodeWorker:
    """One env (its own pybullet client, or the job's Gymnasium world) reused for every episode this process
    records."""

    def __init__(self, job: EpisodeJob):
        self.job = job
        sim = job.sim
        self.env = job.where.make_world(sim.camera, sim.vehicle, sim.control_hz, sim.horizon_s)

    def run(self, episode: int) -> tuple[int, dict[str, list], str, list[np.ndarray]]:
        """Episode ``episode``: its seed, rows, termination and the frames the mosaic shows."""
        job = self.job
        seed = job.base_seed + episode
        record = record_expert_episode if isinstance(self.env, GymWorld) else record_episode
        rows, termination, frames = record(self.env, job.sim, seed, job.where, job.encode)
        picks = np.linspace(0, len(frames) - 1, job.mosaic_columns + 2)[1:-1].astype(int)
        return seed, rows, termination, [frames[i] for i in picks]

    def close(self) -> None:
        self.env.close()
