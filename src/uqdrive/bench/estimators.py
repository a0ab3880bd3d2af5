"""`uqdrive bench estimators`: expected samples of each rate-estimation scheme against Chernoff's fixed n.

At θ = γ = 0.05 by default. Fixed-n schemes always use their planned n. The sequential scheme's
expected sample count E[n] and error P(|η̂ − η| > θ) are exact (dynamic programming over its
stopping rule), not simulated; the SPRT (a decision, no ±θ guarantee) is simulated for reference.
A second table shows what batching costs: one look per ``look_size`` samples keeps that many
workers busy, at the price of overshooting the stopping point by up to look_size − 1.
Targets: E[n] at η = 0.99 ≤ Chernoff/7.5 and, for every η, ≤ 1.12 × fixed-n Clopper–Pearson.
"""

from __future__ import annotations

import argparse

import numpy as np

from uqdrive.uq.bounds import chernoff_n, clopper_pearson_n
from uqdrive.uq.estimators import simulate_sprt
from uqdrive.uq.sequential import sequential_scheme

RATES = (0.0, 0.01, 0.1, 0.5, 0.9, 0.95, 0.99, 1.0)
LOOK_SIZES = (1, 2, 4, 10, 20, 40)
GRID = np.linspace(0, 1, 2001)  # E[n] is continuous in η: its maximum over this grid


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench estimators", description=__doc__)
    ap.add_argument("--theta", type=float, default=0.05)
    ap.add_argument("--gamma", type=float, default=0.05)
    ap.add_argument("--look-size", type=int, default=4, help="samples between looks of the sequential scheme")
    ap.add_argument("--runs", type=int, default=2000, help="simulated SPRTs per rate")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--delta", type=float, default=0.7, help="SPRT threshold for the decision eta >= delta")
    args = ap.parse_args(argv)
    theta, gamma = args.theta, args.gamma
    rng = np.random.default_rng(args.seed)
    scheme = sequential_scheme(theta, gamma, args.look_size)
    n_ch, n_cp = chernoff_n(theta, gamma), clopper_pearson_n(theta, gamma)
    print(f"theta={theta} gamma={gamma} look_size={scheme.look_size} sprt runs={args.runs} seed={args.seed}")
    print(
        f"sequential: calibrated level 1 - {scheme.level:.6f}, at most {scheme.max_n} samples, "
        f"exact worst error {scheme.worst_error():.5f} (allowed {gamma})"
    )
    print(f"sprt: eta >= {args.delta}, indifference +-{theta}, alpha=beta={gamma} (a decision, not a +-theta estimate)")
    print(
        f"{'rate':>5} {'chernoff':>8} {'exact_cp':>8} {'seq_E[n]':>8} {'seq/ch':>6} {'seq/cp':>6} "
        f"{'seq_error':>9} {'sprt_mean':>9} {'sprt/ch':>7}"
    )
    mean_n, error = scheme.operating_characteristics(np.array(RATES))
    for rate, m, e in zip(RATES, mean_n, error):
        _, sprt_used = simulate_sprt(rate, args.runs, rng, args.delta, theta, gamma, gamma)
        print(
            f"{rate:>5g} {n_ch:>8d} {n_cp:>8d} {m:>8.1f} {m / n_ch:>6.3f} {m / n_cp:>6.3f} "
            f"{e:>9.5f} {sprt_used.mean():>9.1f} {sprt_used.mean() / n_ch:>7.3f}"
        )
    print("cost of batching: exact E[n] per look size (each calibrated on its own)")
    print(
        f"{'look_size':>9} {'max_n':>5} "
        + " ".join(f"{f'E[n]@{r:g}':>9}" for r in (0.5, 0.9, 0.99, 1.0))
        + f" {'max E[n]':>8}"
    )
    for size in sorted({*LOOK_SIZES, scheme.look_size}):
        other = sequential_scheme(theta, gamma, size)
        cells = other.operating_characteristics(np.array([0.5, 0.9, 0.99, 1.0]))[0]
        print(
            f"{size:>9d} {other.max_n:>5d} "
            + " ".join(f"{c:>9.1f}" for c in cells)
            + f" {other.operating_characteristics(GRID)[0].max():>8.1f}"
        )
    worst = scheme.operating_characteristics(GRID)[0].max()
    at_099 = scheme.operating_characteristics(0.99)[0][0]
    print(
        f"RESULT estimators saving_at_0.99={n_ch / at_099:.2f} worst_ratio={worst / n_ch:.3f} "
        f"worst_vs_cp={worst / n_cp:.3f}"
    )
    return 0
