"""`uqdrive bench rollout`: closed-loop steps/s with a BNN controller (n = 738 draws) against env-only
steps/s, against the same closed loop rendering 160x120, and with 2 worker processes against 1.

Env-only = the same env (camera rendering, collision and road checks) driven by the
autopilot, whose per-step cost is negligible. Closed loop = the Bayesian controller steers
from each rendered frame. Workloads are fixed step counts (an episode that ends is restarted
with the next seed), so the two are comparable whatever the controller does. The render
comparison drives the camera of ``conf/sim.yaml`` and a 160x120 camera (the render size before
it was the network's own 64x48) in alternating repeats, one process, one torch thread: steps
per second per core; the median ratio is reported. The worker comparison runs chunks of
closed-loop steps through `uqdrive.parallel.ProcessPool` and times the steady state (after each
worker's first chunk, i.e. after process start-up).
Targets: overhead ≤ 2 (closed-loop step at most twice an env-only step), render_speedup ≥ 2,
speedup2 ≥ 1.7. ``env_speedup`` (the env-only ratio of the two cameras) is what rendering alone
gains; render_speedup is that gain diluted by the controller's per-frame cost, the same at both
sizes (run with ``--samples`` to see how the two draw near as the draws get cheaper).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
import time
from pathlib import Path

import torch

from uqdrive.bench.posterior import random_posteriors
from uqdrive.models.checkpoint import load_posterior, save_posterior
from uqdrive.parallel import ProcessPool
from uqdrive.safety.controller import AutopilotPolicy, Policy
from uqdrive.safety.executors import PolicySpec, RolloutJob, RolloutWorker
from uqdrive.sim import DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.sim.config import SimConfig

CONF = Path(__file__).resolve().parents[3] / "conf"
BASELINE_CAMERA = (160, 120)


def drive(env: DrivingEnv, policy: Policy, job: RolloutJob, steps: int, seed: int, render: bool = True) -> float:
    """CPU seconds of this process for ``steps`` control steps (the cost per core, steadier than the wall
    clock on a shared machine), restarting episodes with seeds seed, seed + 1, …"""
    start = time.process_time()
    done, episode = 0, 0
    while done < steps:
        obs = env.reset(seed + episode, job.scenario, job.weather, job.noise, render=render)
        policy.reset(env, seed + episode)
        info = env.last_info
        while not env.done and done < steps:
            command = policy.act(obs, info)
            obs, info = env.step(command.steer, command.speed)
            done += 1
        episode += 1
    return time.process_time() - start


@dataclasses.dataclass(frozen=True)
class ChunkJob:
    """Chunks of ``steps`` closed-loop steps of ``job``'s controller, for `uqdrive.parallel.ProcessPool`."""

    job: RolloutJob
    steps: int

    def worker(self) -> ChunkWorker:
        return ChunkWorker(RolloutWorker(self.job), self.steps)


@dataclasses.dataclass
class ChunkWorker:
    rollouts: RolloutWorker
    steps: int

    def run(self, seed: int) -> float:
        w = self.rollouts
        return drive(w.env, w.policy, w.job, self.steps, seed)

    def close(self) -> None:
        self.rollouts.close()


def throughput(job: RolloutJob, workers: int, chunks: int, steps: int) -> float:
    """Steady-state closed-loop steps per second (wall clock) with ``workers`` processes."""
    first = None
    executor = ProcessPool(workers).executor(ChunkJob(job, steps), owns_pool=True)
    try:
        for i, _ in enumerate(executor.run([1000 * k for k in range(chunks)])):
            if i == workers - 1:
                first = time.perf_counter()
    finally:
        executor.close()
    return (chunks - workers) * steps / (time.perf_counter() - first)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench rollout", description=__doc__)
    ap.add_argument("--samples", type=int, default=738, help="posterior draws per frame")
    ap.add_argument("--method", default="vi", choices=["mcd", "vi", "hmc"])
    ap.add_argument(
        "--models", type=Path, help="drive trained models/<method>.pt from this folder (default: random weights)"
    )
    ap.add_argument("--steps", type=int, default=300, help="steps per timing (env-only, closed loop, each chunk)")
    ap.add_argument("--repeats", type=int, default=3, help="alternating timings of each setting; medians are reported")
    ap.add_argument(
        "--chunks", type=int, default=8, help="chunks per worker comparison (>= 4: each of 2 workers times one)"
    )
    ap.add_argument("--weather", default="clear_noon")
    args = ap.parse_args(argv)
    if args.chunks < 4:
        ap.error(f"--chunks={args.chunks} must be >= 4: 2 workers time only the chunks after their first one")
    torch.set_num_threads(1)
    scenario = ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout.yaml")
    weather = WeatherConfig.from_yaml(CONF / "weather" / f"{args.weather}.yaml")
    camera = SimConfig.from_yaml(CONF / "sim.yaml").camera
    baseline = dataclasses.replace(camera, width=BASELINE_CAMERA[0], height=BASELINE_CAMERA[1])
    with tempfile.TemporaryDirectory() as tmp:
        if args.models is None:
            model = save_posterior(
                random_posteriors(torch.Generator().manual_seed(0))[args.method], Path(tmp) / f"{args.method}.pt"
            )
        else:
            model = args.models / f"{args.method}.pt"
        bins = load_posterior(model, expected_method=args.method).bins  # a trained model's own class set
        spec = PolicySpec("bnn", 6.0, str(model), args.method, bins, samples=args.samples, eps=0.1)
        job = RolloutJob(spec, scenario, weather, 0.0, base_seed=0, camera=camera)
        worker, base_worker = RolloutWorker(job), RolloutWorker(dataclasses.replace(job, camera=baseline))
        for w in (worker, base_worker):
            drive(w.env, w.policy, w.job, 20, 0)  # warm-up
        env_s, loop_s, base_env_s, base_s = [], [], [], []
        for _ in range(args.repeats):
            env_s.append(drive(worker.env, AutopilotPolicy(), job, args.steps, 0))
            loop_s.append(drive(worker.env, worker.policy, job, args.steps, 0))
            base_env_s.append(drive(base_worker.env, AutopilotPolicy(), base_worker.job, args.steps, 0))
            base_s.append(drive(base_worker.env, base_worker.policy, base_worker.job, args.steps, 0))
        worker.close()
        base_worker.close()
        overhead = statistics.median(loop / env for loop, env in zip(loop_s, env_s))
        render_speedup = statistics.median(base / loop for base, loop in zip(base_s, loop_s))
        env_speedup = statistics.median(base / env for base, env in zip(base_env_s, env_s))
        print(
            f"{args.method} controller, n={args.samples} draws, roundabout, {weather.name}, "
            f"{'trained model ' + str(model) if args.models else 'random weights'}, 1 torch thread per process, "
            f"{args.steps} steps x {args.repeats}"
        )
        print(f"env only, {camera.width}x{camera.height}:      {args.steps / statistics.median(env_s):8.1f} steps/s")
        print(
            f"closed loop, {camera.width}x{camera.height}:   {args.steps / statistics.median(loop_s):8.1f} steps/s   "
            f"overhead {overhead:.2f}x (target <= 2)"
        )
        print(
            f"env only, {baseline.width}x{baseline.height}:    "
            f"{args.steps / statistics.median(base_env_s):8.1f} steps/s   "
            f"env speed-up {env_speedup:.2f}x"
        )
        print(
            f"closed loop, {baseline.width}x{baseline.height}: {args.steps / statistics.median(base_s):8.1f} steps/s   "
            f"render speed-up {render_speedup:.2f}x (target >= 2)"
        )
        one = throughput(job, 1, args.chunks, args.steps)
        two = throughput(job, 2, args.chunks, args.steps)
    print(f"1 worker:    {one:8.1f} steps/s")
    print(f"2 workers:   {two:8.1f} steps/s   speed-up {two / one:.2f}x (target >= 1.7)")
    print(
        f"RESULT rollout overhead={overhead:.2f} speedup2={two / one:.2f} render_speedup={render_speedup:.2f} "
        f"env_speedup={env_speedup:.2f}"
    )
    return 0
