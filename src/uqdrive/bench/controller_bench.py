"""`uqdrive bench controller`: per-frame latency and posterior draws of the warning-aware controller on one thread,
the paper's fixed draws against sequential ones, per method, with warnings on and off.

One frame = preprocess (gray 64×48) + trunk + the posterior's draws + π(o), η2 (or its tier), mutual information
+ warning level and action, i.e. `WarningController.act` with the paper's warning config (δ1 0.7, δ2 0.6, τ 0.45,
θ = γ = 0.05; ``--theta 0.1``: the quick profile's 185 draws). ``fixed``: 2 × 738 draws (Chernoff's n for π(o)
and MI, as many for η2), warnings on or off alike. ``sequential``: π(o)'s draws until its mode is settled and
η2's until its tier is decided, each with error ≤ γ outside ±θ, at most 738 each (`uqdrive.policy.draws`).
``recorded``: the warnings-off controller with sequential draws (the avoid stage's off cells): the same π(o),
both streams read to the cap and recorded for the calibration's replay. Frames: what the autopilot sees on the
experiment's road in each weather × noise condition. Each method (random weights of the real architecture, or
--models) decides every frame with a fresh seed; the schemes alternate ``--repeats`` times and each keeps its least
disturbed repeat (the median's lowest). Target: ≤ 10 ms per frame. ``worst_ms``: the slowest method's
median with sequential draws; ``recorded_ratio``: the slowest method's recorded median over its fixed one.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
import yaml

from uqdrive.bench.posterior_bench import random_posteriors
from uqdrive.bench.rollout_bench import CONDITIONS, CONF, experiment_camera, recorded_frames
from uqdrive.models.checkpoint import load_posterior
from uqdrive.policy.controller import Controller
from uqdrive.policy.draws import DrawSettings
from uqdrive.policy.warnings import WarningConfig, WarningController, WarningRule
from uqdrive.sim import ScenarioConfig

TARGET_MS = 10.0
SCHEMES = {"fixed": ("fixed", True), "sequential": ("sequential", True), "recorded": ("sequential", False)}
"""What the bench times: its row's name → (``draws.scheme``, whether the controller acts on warnings)."""


def controller_for(row: str, posterior, bins, config: WarningConfig) -> Controller:
    """The warning controller with ``fixed`` or ``sequential`` draws, or the warnings-off one that records."""
    scheme, warns = SCHEMES[row]
    draws = DrawSettings(scheme, theta=config.theta, gamma=config.gamma)
    if not warns:
        return Controller(posterior, bins, config.samples, 0.1, 8.0, draws)
    return WarningController(posterior, bins, WarningRule(config, draws), 0.1, 8.0, 15.0)


def frame_costs(controller: Controller, frames: list, seed: int, lockstep: int) -> tuple[np.ndarray, np.ndarray]:
    """ms and posterior draws of each frame (a fresh seed each; one warm-up frame first), ``lockstep`` frames per
    call in as many slots (a worker's batch: ms is the call's time over its frames)."""
    controller.reset(seed)
    controller.act(*frames[0])
    ms, draws = np.empty(len(frames)), np.empty(len(frames))
    for start in range(0, len(frames), lockstep):
        batch = frames[start : start + lockstep]
        slots = list(range(len(batch)))
        for slot in slots:
            controller.reset(seed + start + slot, slot)
        began = time.perf_counter()
        commands = controller.act_batch(slots, [frame for frame, _ in batch], [info for _, info in batch])
        ms[start : start + len(batch)] = (time.perf_counter() - began) * 1e3 / len(batch)
        draws[start : start + len(batch)] = [command.draw_count for command in commands]
    return ms, draws


def parse(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="uqdrive bench controller", description=__doc__)
    ap.add_argument("--frames", type=int, default=25, help="recorded frames per weather x noise condition")
    ap.add_argument("--experiment", default="avoid", help="whose road (its first scenario) and render size")
    ap.add_argument("--seed", type=int, default=0, help="seed of the random weights (no trained model) and the draws")
    ap.add_argument(
        "--models",
        type=Path,
        default=Path("models"),
        help="the pipeline's models folder: times <models>/<experiment>/<method>/seed0.pt where they all exist, "
        "else random weights (said so on the RESULT line)",
    )
    ap.add_argument("--methods", nargs="+", default=["mcd", "vi", "hmc"], help="posteriors to time")
    ap.add_argument("--theta", type=float, default=0.05, help="the warning config's theta (0.1: the quick profile)")
    ap.add_argument("--lockstep", type=int, default=1, help="frames decided per call (8: a rollout worker's batch)")
    ap.add_argument("--repeats", type=int, default=3, help="alternating timings of every scheme; the fastest is kept")
    return ap.parse_args(argv)


def posteriors_of(args: argparse.Namespace) -> tuple[dict, str]:
    """The pipeline's trained controllers of ``args.methods`` where all exist, else random weights; and which."""
    trained = {m: args.models / args.experiment / m / "seed0.pt" for m in args.methods}
    if all(path.exists() for path in trained.values()):
        return {m: load_posterior(path, expected_method=m) for m, path in trained.items()}, "trained"
    every = random_posteriors(torch.Generator().manual_seed(args.seed))
    return {m: every[m] for m in args.methods}, "random"


def time_schemes(args: argparse.Namespace, posteriors: dict, bins, config: WarningConfig, frames: list) -> tuple:
    """Per row of `SCHEMES` and method the median ms per frame (printed with the p95 and draws), and the
    sequential row's p95 and median draws per method."""
    medians: dict[str, dict[str, float]] = {row: {} for row in SCHEMES}
    p95s: dict[str, dict[str, float]] = {row: {} for row in SCHEMES}
    draw_medians: dict[str, dict[str, float]] = {row: {} for row in SCHEMES}
    with torch.inference_mode():
        for method, posterior in posteriors.items():
            controllers = {row: controller_for(row, posterior, bins, config) for row in SCHEMES}
            runs: dict[str, list] = {row: [] for row in SCHEMES}
            for _ in range(args.repeats):  # rows alternate; each keeps its least disturbed repeat
                for row, decider in controllers.items():
                    runs[row].append(frame_costs(decider, frames, args.seed, args.lockstep))
            for row in SCHEMES:
                ms, draws = min(runs[row], key=lambda run: float(np.median(run[0])))
                medians[row][method] = float(np.median(ms))
                p95s[row][method], draw_medians[row][method] = float(np.percentile(ms, 95)), float(np.median(draws))
                print(
                    f"{method:>8} {row:>10} {np.median(ms):>9.3f} {np.percentile(ms, 95):>7.3f} "
                    f"{np.median(draws):>12.0f} {draws.mean():>10.1f} {draws.max():>9.0f}"
                )
    return medians, p95s["sequential"], draw_medians["sequential"]


def main(argv: list[str]) -> int:
    args = parse(argv)
    torch.set_num_threads(1)
    posteriors, source = posteriors_of(args)
    bins = next(iter(posteriors.values())).bins  # one experiment's models share its class set
    experiment = yaml.safe_load((CONF / "experiment" / f"{args.experiment}.yaml").read_text())
    scenario = ScenarioConfig.from_yaml(CONF / "scenario" / f"{experiment['scenarios'][0]}.yaml")
    frames = recorded_frames(scenario, experiment_camera(args.experiment), args.frames, every=5)
    config = WarningConfig(theta=args.theta)
    which = f"trained models from {args.models / args.experiment}" if source == "trained" else "random weights"
    print(
        f"{len(frames)} frames ({len(CONDITIONS)} weather x noise conditions, {scenario.name}), 1 thread, {which}, "
        f"{args.lockstep} per call; fixed: 2 x {config.samples} draws; sequential: theta = {config.theta:g}, "
        f"gamma = {config.gamma:g}, at most {config.samples} each"
    )
    print(
        f"{'method':>8} {'scheme':>10} {'median_ms':>9} {'p95_ms':>7} {'median_draws':>12} {'mean_draws':>10} "
        f"{'max_draws':>9}"
    )
    medians, p95s, draw_medians = time_schemes(args, posteriors, bins, config, frames)
    worst = max(medians["sequential"].values())
    speedup = min(medians["fixed"][m] / medians["sequential"][m] for m in posteriors)
    recorded = max(medians["recorded"][m] / medians["fixed"][m] for m in posteriors)
    print(f"target <= {TARGET_MS:g} ms per frame: {'met' if max(p95s.values()) <= TARGET_MS else 'NOT met'} (p95)")
    print(
        f"RESULT controller controller={source} worst_ms={worst:.3f} worst_p95_ms={max(p95s.values()):.3f} "
        f"fixed_worst_ms={max(medians['fixed'].values()):.3f} min_speedup={speedup:.2f} "
        f"median_draws={max(draw_medians.values()):.0f} recorded_ratio={recorded:.2f}"
    )
    return 0
