"""`uqdrive bench rollout`: closed-loop steps/s of a worker stepping ``--lockstep`` rollouts at once with a BNN
controller, against env-only steps/s, against the same closed loop rendering 160x120, and with 2 worker processes
against 1; then the controller's agreement with the paper's fixed 2 x 738 draws on recorded frames.

Env-only = the same envs (camera rendering, collision and road checks) driven by the autopilot, whose per-step
cost is negligible. Closed loop = the Bayesian controller of the offline-safety sweep (no warnings; with
sequential draws no η2 set, as nothing replays its rollouts) steers every env from its rendered frame, the frames
of all envs in one trunk pass per step. Workloads are fixed step counts (an episode that ends is restarted with the
next seed), so the two are comparable whatever the controller does. The render comparison drives the experiment's
camera (`conf/experiment/<name>.yaml`) and a 160x120 camera in alternating repeats, one process, one torch
thread: CPU seconds per step; the median ratio is reported. The worker comparison runs chunks of closed-loop
steps through `uqdrive.parallel.ProcessPool` and times the steady state (after each worker's first chunk).
Agreement: frames the autopilot sees in each weather x noise condition, each decided by the warning controller
with the chosen draws and with the paper's fixed draws (another seed of the fixed draws is the floor: they too
disagree where the posterior is split).
Targets: overhead <= 1.3, speedup2 >= 1.7, agreement >= 0.99. ``env_speedup`` (the env-only ratio of the two
cameras) is what rendering alone gains; render_speedup is that gain diluted by the controller's per-step cost.
``--env highway``: HighwayEnv's roundabout instead, a closed-loop step through the Gymnasium adapter against the
env's own step (`uqdrive.bench.gym_step_bench`).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import torch
import yaml

from uqdrive.bench import gym_step_bench
from uqdrive.bench.posterior_bench import random_posteriors
from uqdrive.models.checkpoint import load_posterior, save_posterior
from uqdrive.parallel import ProcessPool
from uqdrive.policy.draws import DrawSettings
from uqdrive.policy.interface import LockstepPolicy
from uqdrive.policy.recipes import ControllerSpec
from uqdrive.policy.references import ExpertPolicy
from uqdrive.policy.warnings import WarningConfig, WarningController, WarningRule
from uqdrive.safety.executors import RolloutJob
from uqdrive.sim import CameraConfig, DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import SimConfig

CONF = Path(__file__).resolve().parents[3] / "conf"
BASELINE_CAMERA = (160, 120)
CONDITIONS = [(w, s) for w in ("clear_noon", "afternoon", "rain", "fog") for s in (0.0, 0.1)]


def experiment_camera(experiment: str) -> CameraConfig:
    """The camera at the render size conf/experiment/<experiment>.yaml names (conf/render/<W>x<H>.yaml)."""
    spec = yaml.safe_load((CONF / "experiment" / f"{experiment}.yaml").read_text())
    size = next(v for entry in spec["defaults"] if isinstance(entry, dict) for k, v in entry.items() if "render" in k)
    render = yaml.safe_load((CONF / "render" / f"{size}.yaml").read_text())
    return dataclasses.replace(SimConfig().camera, width=render["width"], height=render["height"])


@dataclasses.dataclass
class Driven:
    seconds: float  # CPU seconds of this process
    steps: int
    draws: int  # posterior draws over all steps


def drive(envs: Sequence[DrivingEnv], policy: LockstepPolicy, job: RolloutJob, steps: int, seed: int) -> Driven:
    """``steps`` control steps, ``len(envs)`` episodes at a time in lockstep (every env renders its camera),
    episodes restarted with seeds seed, seed + 1, … as they end."""
    start = time.process_time()
    seeds = iter(range(seed, seed + 10**6))
    frames: list = [None] * len(envs)
    infos: list = [None] * len(envs)

    def begin(slot: int) -> None:
        episode = next(seeds)
        frames[slot] = envs[slot].reset(episode, job.condition(0))
        policy.reset(episode, slot, envs[slot])
        infos[slot] = envs[slot].last_info

    for slot in range(len(envs)):
        begin(slot)
    done = draws = 0
    while done < steps:
        slots = list(range(min(len(envs), steps - done)))
        for slot, command in zip(slots, policy.act_batch(slots, [frames[s] for s in slots], [infos[s] for s in slots])):
            frames[slot], infos[slot] = envs[slot].step(command.steer, command.speed)
            draws += command.draw_count
            if envs[slot].done:
                begin(slot)
        done += len(slots)
    return Driven(time.process_time() - start, done, draws)


@dataclasses.dataclass(frozen=True)
class ChunkJob:
    """Chunks of ``steps`` closed-loop steps of ``job``'s controller on ``width`` envs, for `ProcessPool`."""

    job: RolloutJob
    steps: int
    width: int

    def worker(self) -> ChunkWorker:
        return ChunkWorker(self)


class ChunkWorker:
    def __init__(self, chunk: ChunkJob):
        torch.set_num_threads(1)
        job = chunk.job
        self.chunk, self.policy = chunk, job.policy.build(job.control_hz)
        self.envs = [DrivingEnv(job.camera, job.vehicle, job.control_hz, job.horizon_s) for _ in range(chunk.width)]

    def run(self, seed: int) -> float:
        return drive(self.envs, self.policy, self.chunk.job, self.chunk.steps, seed).seconds

    def close(self) -> None:
        for env in self.envs:
            env.close()


def throughput(chunk: ChunkJob, workers: int, chunks: int) -> float:
    """Steady-state closed-loop steps per second (wall clock) with ``workers`` processes."""
    first = None
    executor = ProcessPool(workers).executor(chunk, owns_pool=True)
    try:
        for i, _ in enumerate(executor.run([1000 * k for k in range(chunks)])):
            if i == workers - 1:
                first = time.perf_counter()
    finally:
        executor.close()
    return (chunks - workers) * chunk.steps / (time.perf_counter() - first)


def recorded_frames(scenario: ScenarioConfig, camera: CameraConfig, per_condition: int, every: int) -> list:
    """(frame, info) the autopilot sees in each weather x noise condition: every ``every``-th frame of its
    episodes (seeds 0, 1, …) until ``per_condition`` are kept."""
    kept = []
    with DrivingEnv(camera) as env:
        for weather_name, noise in CONDITIONS:
            weather = WeatherConfig.from_yaml(CONF / "weather" / f"{weather_name}.yaml")
            count, episode = 0, 0
            while count < per_condition:
                frame, pilot = env.reset(episode, Condition(scenario, weather, noise)), ExpertPolicy()
                pilot.reset(episode, world=env)
                info, step = env.last_info, 0
                while not env.done and count < per_condition:
                    if step % every == 0:
                        kept.append((frame, info))
                        count += 1
                    command = pilot.act(frame, info)
                    frame, info = env.step(command.steer, command.speed)
                    step += 1
                episode += 1
    return kept


def agreement(posterior, bins, draws: DrawSettings, frames: list) -> tuple[float, float, float]:
    """Share of ``frames`` given the same steering class and warning level with ``draws`` as with the paper's fixed
    2 x 738 draws (the warning config's defaults), that of two seeds of the fixed draws, and ``draws``' mean draws
    per frame."""
    config = WarningConfig()
    fixed = WarningController(posterior, bins, WarningRule(config, DrawSettings("fixed")), 0.1, 6.0, 15.0)
    chosen = WarningController(posterior, bins, WarningRule(config, draws), 0.1, 6.0, 15.0)
    same, floor, used = 0, 0, 0
    for i, (frame, info) in enumerate(frames):
        commands = []
        for controller, seed in ((fixed, i), (chosen, i + 10**6), (fixed, i + 2 * 10**6)):
            controller.reset(seed)
            commands.append(controller.act(frame, info))
        reference, mine, again = ((c.steer, c.warning) for c in commands)
        same += reference == mine
        floor += reference == again
        used += commands[1].draw_count
    return same / len(frames), floor / len(frames), used / len(frames)


def parse(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="uqdrive bench rollout", description=__doc__)
    ap.add_argument("--draws", default="sequential", choices=["fixed", "sequential"], help="the controller's draws")
    ap.add_argument("--samples", type=int, default=738, help="fixed: draws per frame for each of π(o) and η2; cap")
    ap.add_argument("--lockstep", type=int, default=8, help="rollouts a worker steps at once")
    ap.add_argument(
        "--method", default="vi", choices=["mcd", "vi", "hmc", "ensemble", "laplace"], help="the posterior that steers"
    )
    ap.add_argument(
        "--models",
        type=Path,
        default=Path("models"),
        help="the pipeline's models folder: drives <models>/<experiment>/<method>/seed0.pt where it exists, else "
        "random weights (said so on the RESULT line)",
    )
    ap.add_argument("--experiment", default="offline", help="whose render size and scenario (its first)")
    ap.add_argument("--steps", type=int, default=400, help="steps per timing (env-only, closed loop, each chunk)")
    ap.add_argument("--repeats", type=int, default=3, help="alternating timings of each setting; medians are reported")
    ap.add_argument(
        "--chunks", type=int, default=8, help="chunks per worker comparison (>= 4: each of 2 workers times one)"
    )
    ap.add_argument("--frames", type=int, default=40, help="recorded frames per weather x noise for the agreement")
    ap.add_argument("--weather", default="clear_noon", help="conf/weather/<name>.yaml")
    ap.add_argument(
        "--env",
        choices=("pybullet", "highway"),
        default="pybullet",
        help="highway: HighwayEnv's roundabout, a closed-loop step through the Gymnasium adapter against the env's "
        "own step (`uqdrive bench gym_step --world highway`, with --steps and --repeats)",
    )
    args = ap.parse_args(argv)
    if args.chunks < 4:
        ap.error(f"--chunks={args.chunks} must be >= 4: 2 workers time only the chunks after their first one")
    return args


def controller_file(args: argparse.Namespace, tmp: Path) -> tuple[Path, str]:
    """The pipeline's trained controller of ``args.method`` if ``args.models`` holds it, else random weights saved
    to ``tmp``; and which of the two it is."""
    trained = args.models / args.experiment / args.method / "seed0.pt"
    if trained.exists():
        return trained, "trained"
    posterior = random_posteriors(torch.Generator().manual_seed(0))[args.method]
    return save_posterior(posterior, tmp / f"{args.method}.pt"), "random"


def time_cameras(args: argparse.Namespace, spec: ControllerSpec, job: RolloutJob, cameras: dict) -> tuple[dict, float]:
    """Env-only and closed-loop CPU seconds per repeat for each camera, alternating; and the closed loop's draws
    per frame at the chosen camera."""
    timings = {size: {"env": [], "loop": []} for size in cameras}
    loop_draws = loop_steps = 0
    for size, cam in cameras.items():
        envs = [DrivingEnv(cam, job.vehicle, job.control_hz, job.horizon_s) for _ in range(args.lockstep)]
        policy = spec.build(job.control_hz)
        drive(envs, policy, job, 20, 0)  # warm-up
        for _ in range(args.repeats):
            timings[size]["env"].append(drive(envs, ExpertPolicy(), job, args.steps, 0).seconds)
            loop = drive(envs, policy, job, args.steps, 0)
            timings[size]["loop"].append(loop.seconds)
            if size == "chosen":
                loop_draws, loop_steps = loop_draws + loop.draws, loop_steps + loop.steps
        for env in envs:
            env.close()
    return timings, loop_draws / loop_steps


def report_cameras(args: argparse.Namespace, cameras: dict, timings: dict, header: str) -> tuple[float, float, float]:
    """Print steps/s per camera; the closed loop's overhead over env-only and both render speed-ups."""
    chosen, base = timings["chosen"], timings["baseline"]
    overhead = statistics.median(loop / env for loop, env in zip(chosen["loop"], chosen["env"]))
    render_speedup = statistics.median(b / c for b, c in zip(base["loop"], chosen["loop"]))
    env_speedup = statistics.median(b / c for b, c in zip(base["env"], chosen["env"]))
    print(header)
    for name, timing in timings.items():
        size = f"{cameras[name].width}x{cameras[name].height}:"
        print(f"env only, {size:<9}    {args.steps / statistics.median(timing['env']):8.1f} steps/s")
        print(f"closed loop, {size:<9} {args.steps / statistics.median(timing['loop']):8.1f} steps/s")
    print(f"overhead {overhead:.2f}x (target <= 1.3), render speed-up {render_speedup:.2f}x, env {env_speedup:.2f}x")
    return overhead, render_speedup, env_speedup


def main(argv: list[str]) -> int:
    args = parse(argv)
    if args.env == "highway":
        return gym_step_bench.main(["--world", "highway", "--steps", str(args.steps), "--repeats", str(args.repeats)])
    torch.set_num_threads(1)
    experiment = yaml.safe_load((CONF / "experiment" / f"{args.experiment}.yaml").read_text())
    scenario = ScenarioConfig.from_yaml(CONF / "scenario" / f"{experiment['scenarios'][0]}.yaml")
    weather = WeatherConfig.from_yaml(CONF / "weather" / f"{args.weather}.yaml")
    camera = experiment_camera(args.experiment)
    cameras = {
        "chosen": camera,
        "baseline": dataclasses.replace(camera, width=BASELINE_CAMERA[0], height=BASELINE_CAMERA[1]),
    }
    draws = DrawSettings(args.draws, unacted="skip")  # the offline-safety sweep's controller: nothing replays it
    with tempfile.TemporaryDirectory() as tmp:
        model, source = controller_file(args, Path(tmp))
        posterior = load_posterior(model, expected_method=args.method)
        bins = posterior.bins  # a trained model's own class set
        spec = ControllerSpec(6.0, str(model), args.method, bins, samples=args.samples, eps=0.1, draws=draws)
        job = RolloutJob(spec, Condition(scenario, weather, 0.0), base_seed=0, camera=camera)
        timings, per_frame_loop = time_cameras(args, spec, job, cameras)
        header = (
            f"{args.method} controller ({source}: {model}), {args.draws} draws (n = {args.samples}), lockstep "
            f"{args.lockstep}, {scenario.name}, {weather.name}, 1 torch thread per process, {args.steps} steps x "
            f"{args.repeats}"
        )
        overhead, render_speedup, env_speedup = report_cameras(args, cameras, timings, header)
        print(f"draws per frame in the closed loop: {per_frame_loop:.1f}")
        chunk = ChunkJob(job, args.steps, args.lockstep)
        one, two = throughput(chunk, 1, args.chunks), throughput(chunk, 2, args.chunks)
        frames = recorded_frames(scenario, camera, args.frames, every=5)
        agree, floor, per_frame = agreement(posterior, bins, draws, frames)
    print(f"1 worker:    {one:8.1f} steps/s")
    print(f"2 workers:   {two:8.1f} steps/s   speed-up {two / one:.2f}x (target >= 1.7)")
    print(
        f"agreement with the fixed 2 x 738 draws on {len(frames)} recorded frames "
        f"({len(CONDITIONS)} weather x noise conditions): {agree:.4f} (two seeds of the fixed draws: {floor:.4f}), "
        f"{per_frame:.1f} draws per frame"
    )
    print(
        f"RESULT rollout controller={source} overhead={overhead:.2f} speedup2={two / one:.2f} "
        f"render_speedup={render_speedup:.2f} env_speedup={env_speedup:.2f} draws_per_frame={per_frame_loop:.1f} "
        f"agreement={agree:.4f}"
    )
    return 0
