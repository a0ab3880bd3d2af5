"""`uqdrive bench posterior`: ms per frame of `Posterior.sample_probs` with n = 738 draws, on one thread.

n = 738 is Chernoff's sample count for θ = γ = 0.05, i.e. what a guaranteed η2 needs per frame.
Each method (MCD, VI, HMC, deep ensemble, last-layer Laplace on the real architecture, randomly
initialised or loaded from --models) is timed vectorised and against a per-draw Python loop doing the same math (trunk
once, then `head_probs(features, 1)` n times). Target: ≤ 10 ms per frame and ≥ 5x the loop.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch

from uqdrive.data.binning import SteeringBins
from uqdrive.models.checkpoint import load_posterior
from uqdrive.models.ensemble import EnsemblePosterior
from uqdrive.models.heads import flatten_mcd_head, he_init_heads, head_size
from uqdrive.models.hmc import HMCPosterior
from uqdrive.models.laplace import LaplacePosterior
from uqdrive.models.mcd import MCDPosterior
from uqdrive.models.pilotnet import Architecture, init_weights
from uqdrive.models.posterior import Posterior
from uqdrive.models.vi import VIPosterior

HMC_STORED = 600  # kept last-layer samples of the paper profile (4 chains x 150)
ENSEMBLE_MEMBERS = 10  # the paper profile's


def random_posteriors(generator: torch.Generator, bins: SteeringBins | None = None) -> dict[str, Posterior]:
    """Every built-in posterior with the real architecture and random (but plausible) weights."""
    mcd = init_weights(MCDPosterior(Architecture(), bins or SteeringBins()), generator).eval()
    vi = VIPosterior.from_mcd(mcd, prior_sigma=1.0, init_sigma=0.05).eval()
    start = flatten_mcd_head(mcd)
    shapes = mcd.arch.head_shapes(mcd.num_classes)
    lower = head_size(shapes[:-1])  # HMC samples the last layer; the three below stay fixed
    samples = start[lower:] + 0.05 * torch.randn((HMC_STORED, len(start) - lower), generator=generator)
    laplace = LaplacePosterior(mcd.arch, mcd.bins)
    laplace.trunk.load_state_dict(mcd.trunk.state_dict())
    laplace.head.copy_(start)
    factor = torch.randn(laplace.covariance.shape, generator=generator, dtype=torch.float64)
    laplace.covariance.copy_(
        0.05 * factor @ factor.T / len(factor) + 1e-3 * torch.eye(len(factor), dtype=torch.float64)
    )
    return {
        "mcd": mcd,
        "vi": vi,
        "hmc": HMCPosterior.from_heads(mcd, samples, start[:lower], len(shapes) - 1).eval(),
        "ensemble": EnsemblePosterior.from_heads(mcd, he_init_heads(ENSEMBLE_MEMBERS, shapes, generator)).eval(),
        "laplace": laplace.eval(),
    }


def _median_ms(fn: Callable[[], torch.Tensor], repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench posterior", description=__doc__)
    ap.add_argument("--samples", type=int, default=738, help="posterior draws per frame")
    ap.add_argument("--batch", type=int, default=1, help="frames per call (1 = a closed-loop controller step)")
    ap.add_argument("--repeats", type=int, default=20, help="timings per posterior; the median is reported")
    ap.add_argument("--seed", type=int, default=0, help="seed of the random weights and the draws")
    ap.add_argument("--models", type=Path, help="time trained models/<method>.pt from this folder instead")
    ap.add_argument("--methods", nargs="+", help="with --models: which models/<method>.pt (default: every built-in)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    generator = torch.Generator().manual_seed(args.seed)
    if args.models is None:
        posteriors = random_posteriors(generator)
    else:
        methods = args.methods or list(random_posteriors(generator))
        posteriors = {m: load_posterior(args.models / f"{m}.pt", expected_method=m) for m in methods}
    x = torch.rand((args.batch, 1, 48, 64), generator=generator)
    n = args.samples
    print(
        f"n={n} draws, batch={args.batch} frame(s), 1 thread, median of {args.repeats}, "
        f"{'trained models from ' + str(args.models) if args.models else 'random weights'}"
    )
    print(f"{'method':>8} {'vector_ms/frame':>15} {'loop_ms/frame':>13} {'speedup':>7}")
    worst, min_speedup = 0.0, float("inf")
    with torch.no_grad():
        for method, post in posteriors.items():
            fast = _median_ms(lambda: post.sample_probs(x, n, generator), args.repeats) / args.batch

            def loop(post: Posterior = post) -> torch.Tensor:
                features = post.features(x)
                return torch.cat([post.head_probs(features, 1, generator) for _ in range(n)])

            slow = _median_ms(loop, max(3, args.repeats // 4)) / args.batch
            worst, min_speedup = max(worst, fast), min(min_speedup, slow / fast)
            print(f"{method:>8} {fast:>15.3f} {slow:>13.3f} {slow / fast:>7.1f}")
    print(f"RESULT posterior worst_ms={worst:.3f} min_speedup={min_speedup:.1f}")
    return 0
