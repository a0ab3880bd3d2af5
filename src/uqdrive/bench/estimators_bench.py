"""`uqdrive bench estimators`: expected samples of each rate-estimation scheme against Chernoff's fixed n.

At θ = γ = 0.05 by default. Fixed-n schemes always use their planned n. The sequential scheme's
expected sample count E[n] and error P(η ∉ interval) are exact (dynamic programming over its
stopping rule), not simulated, for today's rule (fit and ball rules) and, beside it, the previous one
(the fit rule alone at the same calibrated level); the SPRT (a decision, no ±θ guarantee) is simulated
for reference. A second table shows what batching costs: one look per ``look_size`` samples keeps
that many workers busy, at the price of overshooting the stopping point by up to look_size − 1. Then
the cost of calibrating at an untabulated γ (γ/split, as a family-wise split over cells does), against
calibrating the fit rule alone in the same run.
Targets: E[n] at η = 0.99 ≤ Chernoff/14.7 and, for every η, ≤ 1.12 × fixed-n Clopper–Pearson.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from uqdrive.uq.bounds import chernoff_n, clopper_pearson_n
from uqdrive.uq.estimators import simulate_sprt
from uqdrive.uq.sequential import SequentialScheme, calibrate_ball_level, calibrate_level, sequential_scheme

RATES = (0.0, 0.01, 0.05, 0.1, 0.5, 0.9, 0.95, 0.99, 1.0)
LOOK_SIZES = (1, 2, 4, 10, 20, 40)
GRID = np.linspace(0, 1, 2001)  # E[n] is continuous in η: its maximum over this grid


def _previous(scheme: SequentialScheme) -> SequentialScheme:
    """The rule this one extends: the fit rule alone at the same calibrated level."""
    return SequentialScheme(scheme.theta, scheme.gamma, scheme.look_size, scheme.level)


def _calibration_cost(theta: float, gamma: float, look_size: int) -> tuple[float, float, float, float, float]:
    """(seconds for both levels, CPU seconds for them, seconds for the fit level alone, level, ball level) at an
    untabulated γ (wall time counts other work on the machine; CPU time does not)."""
    start, cpu = time.perf_counter(), time.process_time()
    level = calibrate_level(theta, gamma, look_size)
    fit_only = time.perf_counter() - start
    ball = calibrate_ball_level(theta, gamma, look_size, level)
    return time.perf_counter() - start, time.process_time() - cpu, fit_only, level, ball


def print_batching_cost(theta: float, gamma: float, look_size: int) -> None:
    """Exact E[n] per look size, each scheme calibrated on its own (the previous rule in brackets)."""
    print("cost of batching: exact E[n] per look size (each calibrated on its own; previous rule in brackets)")
    print(
        f"{'look_size':>9} {'max_n':>5} "
        + " ".join(f"{f'E[n]@{r:g}':>15}" for r in (0.5, 0.9, 0.99, 1.0))
        + f" {'max E[n]':>8}"
    )
    for size in sorted({*LOOK_SIZES, look_size}):
        other = sequential_scheme(theta, gamma, size)
        cells = other.operating_characteristics(np.array([0.5, 0.9, 0.99, 1.0]))[0]
        before = _previous(other).operating_characteristics(np.array([0.5, 0.9, 0.99, 1.0]))[0]
        print(
            f"{size:>9d} {other.max_n:>5d} "
            + " ".join(f"{c:>7.1f} ({b:>5.1f})" for c, b in zip(cells, before))
            + f" {other.operating_characteristics(GRID)[0].max():>8.1f}"
        )


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench estimators", description=__doc__)
    ap.add_argument("--theta", type=float, default=0.05, help="absolute error bound, in (0, 1)")
    ap.add_argument("--gamma", type=float, default=0.05, help="allowed failure probability, in (0, 1)")
    ap.add_argument("--look-size", type=int, default=4, help="samples between looks of the sequential scheme")
    ap.add_argument("--runs", type=int, default=2000, help="simulated SPRTs per rate")
    ap.add_argument("--seed", type=int, default=0, help="seed of the simulated outcomes")
    ap.add_argument("--delta", type=float, default=0.7, help="SPRT threshold for the decision eta >= delta")
    ap.add_argument("--split", type=int, default=36, help="calibrate once at the untabulated gamma / split")
    args = ap.parse_args(argv)
    theta, gamma = args.theta, args.gamma
    rng = np.random.default_rng(args.seed)
    scheme = sequential_scheme(theta, gamma, args.look_size)
    previous = _previous(scheme)
    n_ch, n_cp = chernoff_n(theta, gamma), clopper_pearson_n(theta, gamma)
    print(f"theta={theta} gamma={gamma} look_size={scheme.look_size} sprt runs={args.runs} seed={args.seed}")
    print(
        f"sequential: fit level 1 - {scheme.level:.6f}, ball level {scheme.ball_level:.6f}, at most {scheme.max_n} "
        f"samples, exact worst error {scheme.worst_error():.5f} (allowed {gamma}); previous rule (fit alone): at most "
        f"{previous.max_n}, worst error {previous.worst_error():.5f}"
    )
    print(f"sprt: eta >= {args.delta}, indifference +-{theta}, alpha=beta={gamma} (a decision, not a +-theta estimate)")
    print(
        f"{'rate':>5} {'chernoff':>8} {'exact_cp':>8} {'seq_E[n]':>8} {'prev_E[n]':>9} {'seq/ch':>6} {'seq/cp':>6} "
        f"{'seq_error':>9} {'prev_error':>10} {'sprt_mean':>9}"
    )
    mean_n, error = scheme.operating_characteristics(np.array(RATES))
    prev_n, prev_error = previous.operating_characteristics(np.array(RATES))
    for rate, m, e, pm, pe in zip(RATES, mean_n, error, prev_n, prev_error):
        _, sprt_used = simulate_sprt(rate, args.runs, rng, args.delta, theta, gamma, gamma)
        print(
            f"{rate:>5g} {n_ch:>8d} {n_cp:>8d} {m:>8.1f} {pm:>9.1f} {m / n_ch:>6.3f} {m / n_cp:>6.3f} "
            f"{e:>9.5f} {pe:>10.5f} {sprt_used.mean():>9.1f}"
        )
    print_batching_cost(theta, gamma, scheme.look_size)
    seconds, cpu, fit_only, level, ball = _calibration_cost(theta, gamma / args.split, scheme.look_size)
    print(
        f"calibration at the untabulated gamma={gamma}/{args.split}, look {scheme.look_size}: {seconds:.2f} s, "
        f"{cpu:.2f} s of CPU (fit level {level:.6g}, ball level {ball:.6g}); the fit rule alone {fit_only:.2f} s"
    )
    worst = scheme.operating_characteristics(GRID)[0].max()
    print(
        f"RESULT estimators saving_at_0.99={n_ch / mean_n[RATES.index(0.99)]:.2f} worst_vs_cp={worst / n_cp:.3f} "
        f"en_at_0={mean_n[RATES.index(0.0)]:.1f} en_at_1={mean_n[RATES.index(1.0)]:.1f} "
        f"calibrate_s={seconds:.2f} calibrate_cpu_s={cpu:.2f} calibrate_vs_fit_only={seconds / fit_only:.2f}"
    )
    return 0
