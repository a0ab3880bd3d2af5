"""`uqdrive bench threshold`: draws the sequential threshold test needs against the fixed-n controller's.

The per-frame controller decides "is η2 ≥ δ?" for its warning tiers; the paper's fixed-n controller
draws Chernoff's n (738 at θ = γ = 0.05) every frame. The sequential test (:mod:`uqdrive.uq.threshold`,
forced at that cap, indifference ±θ) is shown per look schedule: its calibrated levels, its exact
worst errors and its exact expected draws E[n] at several η, with the time to build it (once per
parameter set and process). Then an envelope certifier (unforced, θ = 0, γ split over regions):
P(certified above), P(certified below) and E[n]. All figures are exact (dynamic programming).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from uqdrive.uq.bounds import chernoff_n
from uqdrive.uq.threshold import ThresholdTest, doubling_looks

RATES = (0.0, 0.5, 0.6, 0.65, 0.7, 0.75, 0.8, 0.9, 0.95, 0.99, 1.0)
CERTIFIER_RATES = (0.5, 0.8, 0.85, 0.9, 0.95, 0.99, 1.0)


def _schedules(cap: int) -> dict[str, tuple[int, ...]]:
    return {
        "every 1": tuple(range(1, cap + 1)),
        "every 4": (*range(4, cap, 4), cap),
        "every 8": (*range(8, cap, 8), cap),
        "doubling from 8": doubling_looks(8, cap),
    }


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench threshold", description=__doc__)
    ap.add_argument("--deltas", type=float, nargs="+", default=[0.7, 0.6], help="thresholds (paper: delta1, delta2)")
    ap.add_argument("--theta", type=float, default=0.05, help="indifference half-width; the cap is Chernoff's n")
    ap.add_argument("--gamma", type=float, default=0.05, help="allowed failure probability, in (0, 1)")
    ap.add_argument("--regions", type=int, default=20, help="certifier: gamma split over this many regions")
    ap.add_argument("--tau", type=float, default=0.9, help="certifier threshold on eta1")
    ap.add_argument("--budget", type=int, default=400, help="certifier: most rollouts per region (looks every 20)")
    args = ap.parse_args(argv)
    cap = chernoff_n(args.theta, args.gamma)
    print(f"controller: theta={args.theta} gamma={args.gamma} cap={cap} (the fixed-n controller draws {cap})")
    rates = " ".join(f"{r:>6g}" for r in RATES)
    print(f"{'delta':>5} {'looks':>15} {'build_s':>7} {'errors (above, below)':>22}  E[n] at eta = {rates}")
    headline = {}
    for delta in args.deltas:
        for name, looks in _schedules(cap).items():
            start = time.perf_counter()
            test = ThresholdTest(delta, args.gamma, looks, theta=args.theta, forced=True)
            seconds = time.perf_counter() - start
            _, _, mean_n = test.operating_characteristics(np.array(RATES))
            errors = ", ".join(f"{e:.4f}" for e in test.worst_errors())
            expected = " ".join(f"{m:>6.1f}" for m in mean_n)
            print(f"{delta:>5g} {name:>15} {seconds:>7.2f} {errors:>22}                {expected}")
            if delta == args.deltas[0] and name == "every 4":
                headline = {"en_at_1": mean_n[-1], "en_at_0.9": mean_n[RATES.index(0.9)], "build_s": seconds}
                headline["worst_en"] = test.operating_characteristics(np.linspace(0, 1, 1001))[2].max()
    gamma = args.gamma / args.regions
    certifier = ThresholdTest(args.tau, gamma, tuple(range(20, args.budget + 1, 20)), theta=0.0, forced=False)
    above, below, mean_n = certifier.operating_characteristics(np.array(CERTIFIER_RATES))
    print(
        f"certifier: eta1 >= {args.tau}? gamma={args.gamma}/{args.regions}, looks every 20 up to {args.budget}, "
        f"exact worst errors {', '.join(f'{e:.5f}' for e in certifier.worst_errors())}"
    )
    print(f"{'eta':>5} {'P(above)':>9} {'P(below)':>9} {'E[n]':>6}")
    for rate, a, b, m in zip(CERTIFIER_RATES, above, below, mean_n):
        print(f"{rate:>5g} {a:>9.4f} {b:>9.4f} {m:>6.1f}")
    print(
        f"RESULT threshold en_at_1={headline['en_at_1']:.1f} saving_at_1={cap / headline['en_at_1']:.1f} "
        f"en_at_0.9={headline['en_at_0.9']:.1f} worst_en={headline['worst_en']:.1f} "
        f"worst_vs_fixed={headline['worst_en'] / cap:.3f} build_s={headline['build_s']:.2f}"
    )
    return 0
