"""`uqdrive bench controller`: per-frame latency of the full warning-aware controller on one thread.

One frame = preprocess (gray 64×48) + posterior with 2n draws (n = 738: Chernoff's n for
θ = γ = 0.05; n for π(o) and mutual information, n separate ones for η2)
+ π(o), η2, mutual information + warning level and action, i.e. `WarningController.act` on a
rendered 160×120 camera frame of the obstacle road. Each method (random weights of the real
architecture, or --models) is timed over --frames calls with fresh draws; the parts are timed
separately to show where the time goes. Target: ≤ 10 ms per frame (20 Hz with room to spare).
``worst_ms``: the slowest method's median; ``worst_p95_ms``: its 95th percentile.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from uqdrive.bench.posterior import random_posteriors
from uqdrive.data.datasets import to_inputs
from uqdrive.data.frames import preprocess_frame
from uqdrive.models.checkpoint import load_posterior
from uqdrive.safety.warnings import WarningConfig, WarningController, classify
from uqdrive.sim import DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.uq import frame_measures

CONF = Path(__file__).resolve().parents[3] / "conf"
TARGET_MS = 10.0


def _times_ms(fn: Callable[[], object], repeats: int) -> np.ndarray:
    fn()  # warm-up
    out = np.empty(repeats)
    for i in range(repeats):
        start = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - start
    return out * 1e3


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench controller", description=__doc__)
    ap.add_argument("--theta", type=float, default=0.05, help="η2 accuracy per frame; draws = chernoff_n(θ, γ)")
    ap.add_argument("--gamma", type=float, default=0.05)
    ap.add_argument("--frames", type=int, default=200, help="timed frames per method")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--models", type=Path, help="time trained models/<method>.pt from this folder instead")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    config = WarningConfig(theta=args.theta, gamma=args.gamma)
    generator = torch.Generator().manual_seed(args.seed)
    if args.models is None:
        posteriors = random_posteriors(generator)
    else:
        posteriors = {m: load_posterior(args.models / f"{m}.pt", expected_method=m) for m in ("mcd", "vi", "hmc")}
    bins = next(iter(posteriors.values())).bins  # one experiment's models share its class set
    with DrivingEnv() as env:
        frame = env.reset(
            args.seed,
            ScenarioConfig.from_yaml(CONF / "scenario" / "obstacle.yaml"),
            WeatherConfig.from_yaml(CONF / "weather" / "clear_noon.yaml"),
        )
        info = env.last_info
    centres = torch.as_tensor(bins.centres, dtype=torch.float32)
    x = to_inputs(preprocess_frame(frame)[None])
    n = 2 * config.samples
    source = f"trained models from {args.models}" if args.models else "random weights"
    print(
        f"{n} draws per frame (2 x chernoff_n({args.theta:g}, {args.gamma:g}): pi(o) and eta2 draw separately), "
        f"frame {frame.shape[1]}x{frame.shape[0]}, 1 thread, {args.frames} frames, {source}"
    )
    print(
        f"{'method':>6} {'median_ms':>9} {'p95_ms':>7} {'max_ms':>7} | {'preproc':>7} {'posterior':>9} "
        f"{'measures':>8} {'warning':>7}  (medians, ms)"
    )
    worst, worst_p95 = 0.0, 0.0
    with torch.inference_mode():  # as the controller runs
        for method, posterior in posteriors.items():
            controller = WarningController(posterior, bins, config, eps=0.1, speed=8.0, control_hz=15.0)
            controller.reset(None, args.seed)
            full = _times_ms(lambda: controller.act(frame, info), args.frames)
            probs = posterior.sample_probs(x, n, generator)
            measures = frame_measures(probs, centres, 0.1, split=config.samples)
            e2, mi = float(measures.eta2[0]), float(measures.mutual_information[0])
            parts = [
                statistics.median(_times_ms(fn, max(20, args.frames // 4)))
                for fn in (
                    lambda: to_inputs(preprocess_frame(frame)[None]),
                    lambda: posterior.sample_probs(x, n, generator),
                    lambda: frame_measures(probs, centres, 0.1, split=config.samples),
                    lambda: controller.actions.step(classify(e2, mi, config.delta1, config.delta2, config.tau)),
                )
            ]
            median, p95 = float(np.median(full)), float(np.percentile(full, 95))
            worst, worst_p95 = max(worst, median), max(worst_p95, p95)
            print(
                f"{method:>6} {median:>9.3f} {p95:>7.3f} {full.max():>7.3f} | {parts[0]:>7.3f} {parts[1]:>9.3f} "
                f"{parts[2]:>8.3f} {parts[3]:>7.3f}"
            )
    print(f"target <= {TARGET_MS:g} ms per frame: {'met' if worst_p95 <= TARGET_MS else 'NOT met'} (95th percentile)")
    print(f"RESULT controller worst_ms={worst:.3f} worst_p95_ms={worst_p95:.3f}")
    return 0
