"""`uqdrive bench tier`: what building a tier rule costs, now that every build computes its exact error.

Per setting (the quick profile's θ = 0.1, cap 185; the paper's θ = 0.05, cap 738): a `TierTest` built from
nothing (its two threshold tests calibrated, then its exact wrong-tier error by dynamic programming over its
stopping rule on 2001 η2 points and the zone edges), the error computation alone, and a calibration's whole
candidate grid (every (δ1, δ2) of conf/avoid.yaml's deltas with 0, as `uqdrive.uq.tier.tier_rule` caches them once
per process). ``error_share``: the error computation's part of a build from nothing. A controller builds its rule
once (a calibrated cell's worker receives it built); no frame pays for it.
"""

from __future__ import annotations

import argparse
import itertools
import time

from uqdrive.uq import tier
from uqdrive.uq.bounds import chernoff_n
from uqdrive.uq.threshold import _calibrated

GRID = (0.0, 0.5, 0.6, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95, 0.97, 0.98, 0.99, 0.995, 1.0)


def timed(build):
    start = time.perf_counter()
    out = build()
    return out, time.perf_counter() - start


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench tier", description=__doc__)
    ap.add_argument("--gamma", type=float, default=0.05, help="allowed failure probability, in (0, 1)")
    args = ap.parse_args(argv)
    print(f"{'theta':>5} {'cap':>4} {'build_s':>8} {'error_s':>8} {'grid_rules':>10} {'grid_s':>7} {'worst_error':>11}")
    shares = []
    for theta in (0.1, 0.05):
        cap = chernoff_n(theta, args.gamma)
        _calibrated.cache_clear()
        tier.tier_rule.cache_clear()
        rule, build_s = timed(lambda: tier.TierTest(0.7, 0.6, args.gamma, theta, 8, cap))
        _, error_s = timed(lambda: tier._exact_error(rule))
        pairs = [(d1, d2) for d1, d2 in itertools.product(GRID, GRID) if d2 <= d1]
        rules, grid_s = timed(lambda: [tier.tier_rule(tier.TierTest, *p, args.gamma, theta, 8, cap) for p in pairs])
        worst = max(r.error for r in rules)
        shares.append(error_s / build_s)
        print(f"{theta:>5g} {cap:>4} {build_s:>8.3f} {error_s:>8.3f} {len(rules):>10} {grid_s:>7.2f} {worst:>11.4f}")
    print(f"RESULT tier error_share_quick={shares[0]:.2f} error_share_paper={shares[1]:.2f}")
    return 0
