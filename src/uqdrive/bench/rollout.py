"""`uqdrive bench rollout`: closed-loop steps/s with a BNN controller (n = 738 draws) against env-only
steps/s, and rollout throughput with 2 worker processes against 1.

Env-only = the same env (camera rendering, collision and road checks) driven by the
autopilot, whose per-step cost is negligible. Closed loop = the Bayesian controller steers
from each rendered frame. Workloads are fixed step counts (an episode that ends is restarted
with the next seed), so the two are comparable whatever the controller does. The worker
comparison runs chunks of closed-loop steps through `uqdrive.parallel.map_ordered` and times
the steady state (after each worker's first chunk, i.e. after process start-up).
Targets: overhead ≤ 2 (closed-loop step at most twice an env-only step), speedup2 ≥ 1.7.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import torch

from uqdrive.bench.posterior import random_posteriors
from uqdrive.models.checkpoint import save_posterior
from uqdrive.parallel import map_ordered
from uqdrive.safety.controller import AutopilotPolicy, Policy
from uqdrive.safety.executors import PolicySpec, RolloutJob, RolloutWorker
from uqdrive.sim import DrivingEnv, ScenarioConfig, WeatherConfig

CONF = Path(__file__).resolve().parents[3] / "conf"


def drive(env: DrivingEnv, policy: Policy, job: RolloutJob, steps: int, seed: int, render: bool = True) -> float:
    """Seconds for ``steps`` control steps, restarting episodes with seeds seed, seed + 1, …"""
    start = time.perf_counter()
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
    return time.perf_counter() - start


_state: dict[str, object] = {}


def _init(job: RolloutJob, steps: int) -> None:
    _state.update(worker=RolloutWorker(job), steps=steps)


def _chunk(seed: int) -> float:
    worker = _state["worker"]
    return drive(worker.env, worker.policy, worker.job, _state["steps"], seed)


def throughput(job: RolloutJob, workers: int, chunks: int, steps: int) -> float:
    """Steady-state closed-loop steps per second (wall clock) with ``workers`` processes."""
    first = None
    for i, _ in enumerate(map_ordered(_chunk, [1000 * k for k in range(chunks)], workers, _init, (job, steps))):
        if i == workers - 1:
            first = time.perf_counter()
    _state.clear()
    return (chunks - workers) * steps / (time.perf_counter() - first)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench rollout", description=__doc__)
    ap.add_argument("--samples", type=int, default=738, help="posterior draws per frame")
    ap.add_argument("--method", default="vi", choices=["mcd", "vi", "hmc"])
    ap.add_argument("--models", type=Path, help="drive trained models/<method>.pt from this folder (default: random weights)")
    ap.add_argument("--steps", type=int, default=300, help="steps per timing (env-only, closed loop, each chunk)")
    ap.add_argument("--chunks", type=int, default=8, help="chunks per worker comparison (> 2)")
    ap.add_argument("--weather", default="clear_noon")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    scenario = ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout.yaml")
    weather = WeatherConfig.from_yaml(CONF / "weather" / f"{args.weather}.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        if args.models is None:
            model = save_posterior(random_posteriors(torch.Generator().manual_seed(0))[args.method],
                                   Path(tmp) / f"{args.method}.pt")
        else:
            model = args.models / f"{args.method}.pt"
        spec = PolicySpec("bnn", 6.0, str(model), args.method, samples=args.samples, eps=0.1)
        job = RolloutJob(spec, scenario, weather, 0.0, base_seed=0)
        worker = RolloutWorker(job)
        drive(worker.env, worker.policy, job, 20, 0)  # warm-up
        env_s = drive(worker.env, AutopilotPolicy(), job, args.steps, 0)
        loop_s = drive(worker.env, worker.policy, job, args.steps, 0)
        worker.close()
        env_sps, loop_sps = args.steps / env_s, args.steps / loop_s
        print(f"{args.method} controller, n={args.samples} draws, roundabout, {weather.name}, "
              f"{'trained model ' + str(model) if args.models else 'random weights'}, 1 torch thread per process")
        print(f"env only:    {env_sps:8.1f} steps/s")
        print(f"closed loop: {loop_sps:8.1f} steps/s   overhead {env_sps / loop_sps:.2f}x (target <= 2)")
        one = throughput(job, 1, args.chunks, args.steps)
        two = throughput(job, 2, args.chunks, args.steps)
    print(f"1 worker:    {one:8.1f} steps/s")
    print(f"2 workers:   {two:8.1f} steps/s   speed-up {two / one:.2f}x (target >= 1.7)")
    print(f"RESULT rollout overhead={env_sps / loop_sps:.2f} speedup2={two / one:.2f}")
    return 0
