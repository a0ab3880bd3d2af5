"""`uqdrive bench controller`: per-frame latency and posterior draws of the warning-aware controller on one thread,
the paper's fixed draws against sequential ones, per method.

One frame = preprocess (gray 64×48) + trunk + the posterior's draws + π(o), η2 (or its tier), mutual information
+ warning level and action, i.e. `WarningController.act` with the paper's warning config (δ1 0.7, δ2 0.6, τ 0.45,
θ = γ = 0.05). ``fixed``: 2 × 738 draws (Chernoff's n for π(o) and MI, as many for η2). ``sequential``: π(o)'s
draws until its mode is settled and η2's until its tier is decided, each with error ≤ γ outside ±θ, at most 738
each (`uqdrive.safety.draws`). Frames: what the autopilot sees on the experiment's road in each weather × noise
condition. Each method (random weights of the real architecture, or --models) decides every frame with a fresh
seed. Target: ≤ 10 ms per frame. ``worst_ms``: the slowest method's median with sequential draws.
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
from uqdrive.safety.draws import DrawSettings
from uqdrive.safety.warnings import WarningConfig, WarningController
from uqdrive.sim import ScenarioConfig

TARGET_MS = 10.0
SCHEMES = ("fixed", "sequential")


def frame_costs(controller: WarningController, frames: list, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """ms and posterior draws of each frame (a fresh seed each; one warm-up frame first)."""
    controller.reset(None, seed)
    controller.act(*frames[0])
    ms, draws = np.empty(len(frames)), np.empty(len(frames))
    for i, (frame, info) in enumerate(frames):
        controller.reset(None, seed + i)
        start = time.perf_counter()
        command = controller.act(frame, info)
        ms[i] = (time.perf_counter() - start) * 1e3
        draws[i] = command.draws
    return ms, draws


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench controller", description=__doc__)
    ap.add_argument("--frames", type=int, default=25, help="recorded frames per weather x noise condition")
    ap.add_argument("--experiment", default="avoid", help="whose road (its first scenario) and render size")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--models",
        type=Path,
        default=Path("models"),
        help="the pipeline's models folder: times <models>/<experiment>/<method>/seed0.pt where they all exist, "
        "else random weights (said so on the RESULT line)",
    )
    ap.add_argument("--methods", nargs="+", default=["mcd", "vi", "hmc"])
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    trained = {m: args.models / args.experiment / m / "seed0.pt" for m in args.methods}
    controller = "trained" if all(path.exists() for path in trained.values()) else "random"
    if controller == "random":
        every = random_posteriors(torch.Generator().manual_seed(args.seed))
        posteriors = {m: every[m] for m in args.methods}
    else:
        posteriors = {m: load_posterior(path, expected_method=m) for m, path in trained.items()}
    bins = next(iter(posteriors.values())).bins  # one experiment's models share its class set
    experiment = yaml.safe_load((CONF / "experiment" / f"{args.experiment}.yaml").read_text())
    scenario = ScenarioConfig.from_yaml(CONF / "scenario" / f"{experiment['scenarios'][0]}.yaml")
    frames = recorded_frames(scenario, experiment_camera(args.experiment), args.frames, every=5)
    config = WarningConfig()
    source = f"trained models from {args.models / args.experiment}" if controller == "trained" else "random weights"
    print(
        f"{len(frames)} frames ({len(CONDITIONS)} weather x noise conditions, {scenario.name}), 1 thread, {source}; "
        f"fixed: 2 x {config.samples} draws; sequential: theta = gamma = 0.05, at most {config.samples} each"
    )
    print(
        f"{'method':>8} {'scheme':>10} {'median_ms':>9} {'p95_ms':>7} {'median_draws':>12} {'mean_draws':>10} "
        f"{'max_draws':>9}"
    )
    medians: dict[str, dict[str, float]] = {scheme: {} for scheme in SCHEMES}
    p95s, draw_medians = {}, {}
    with torch.inference_mode():
        for method, posterior in posteriors.items():
            for scheme in SCHEMES:
                controller = WarningController(posterior, bins, config, 0.1, 8.0, 15.0, DrawSettings(scheme))
                ms, draws = frame_costs(controller, frames, args.seed)
                medians[scheme][method] = float(np.median(ms))
                if scheme == "sequential":
                    p95s[method], draw_medians[method] = float(np.percentile(ms, 95)), float(np.median(draws))
                print(
                    f"{method:>8} {scheme:>10} {np.median(ms):>9.3f} {np.percentile(ms, 95):>7.3f} "
                    f"{np.median(draws):>12.0f} {draws.mean():>10.1f} {draws.max():>9.0f}"
                )
    worst = max(medians["sequential"].values())
    speedup = min(medians["fixed"][m] / medians["sequential"][m] for m in posteriors)
    print(f"target <= {TARGET_MS:g} ms per frame: {'met' if max(p95s.values()) <= TARGET_MS else 'NOT met'} (p95)")
    print(
        f"RESULT controller controller={controller} worst_ms={worst:.3f} worst_p95_ms={max(p95s.values()):.3f} "
        f"fixed_worst_ms={max(medians['fixed'].values()):.3f} min_speedup={speedup:.2f} "
        f"median_draws={max(draw_medians.values()):.0f}"
    )
    return 0
