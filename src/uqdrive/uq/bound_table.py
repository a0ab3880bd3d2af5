"""`uqdrive bound`: how many samples each scheme plans (or needs at worst) for a given (θ, γ)."""

from __future__ import annotations

import argparse
import sys

from uqdrive.uq.bounds import chernoff_n, clopper_pearson_n, massart_n
from uqdrive.uq.estimators import sprt_cap
from uqdrive.uq.sequential import sequential_scheme

RATES = (0.5, 0.9, 0.95, 0.99, 1.0)


def table(theta: float, gamma: float, rate_bounds: list[float], delta: float, look_size: int = 1) -> list[str]:
    """Rows of the sample-count table; raises ``ValueError`` on bad arguments."""
    scheme = sequential_scheme(theta, gamma, look_size)
    rows = [
        ("chernoff (paper, n > ln(2/g)/(2 t^2))", chernoff_n(theta, gamma), "planned", "yes"),
        ("clopper_pearson (exact, fixed n)", clopper_pearson_n(theta, gamma), "planned", "yes"),
    ]
    rows += [
        (
            f"massart, a priori min(eta,1-eta) <= {b:g}",
            massart_n(theta, gamma, b),
            "planned",
            "yes" if b >= 0.5 else "yes, if the bound holds",
        )
        for b in rate_bounds
    ]
    rows.append(
        (
            f"sequential (calibrated fit and ball rules), a look every {scheme.look_size}",
            scheme.max_n,
            "worst case",
            "yes (exact error computed)",
        )
    )
    sprt_name = f"sprt eta >= {delta:g} +- {theta:g} (cap)"
    if 0 < delta - theta and delta + theta < 1:
        rows.append((sprt_name, sprt_cap(delta, theta, gamma, gamma), "worst case", "no (decision only)"))
    else:  # the indifference region leaves (0, 1): the SPRT is undefined, the other schemes are not
        rows.append((sprt_name, "n/a", "", "no (needs 0 < delta +- theta < 1; set --delta)"))
    width = max(len(r[0]) for r in rows)
    out = [
        f"samples so that P(|estimate - eta| > theta) <= gamma, theta={theta:g}, gamma={gamma:g}",
        f"{'scheme':<{width}}  {'samples':>7}  {'kind':<10}  guaranteed",
    ]
    out += [f"{name:<{width}}  {n:>7}  {kind:<10}  {g}" for name, n, kind, g in rows]
    mean_n, _ = scheme.operating_characteristics(RATES)
    expected = ", ".join(f"{m:.1f} at eta={r:g}" for r, m in zip(RATES, mean_n))
    out.append(
        f"sequential: stops when the exact interval at level {1 - scheme.level:.5f} fits in k/n +-theta, or a ball "
        f"c +-theta has edge tails sqrt(2(U^2 + L^2)) <= {scheme.ball_level:.5f} (reports c); "
        f"expected samples {expected}"
    )
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bound", description=__doc__)
    ap.add_argument("--theta", type=float, default=0.05, help="absolute error bound, in (0, 1)")
    ap.add_argument("--gamma", type=float, default=0.05, help="allowed failure probability, in (0, 1)")
    ap.add_argument(
        "--rate-bounds",
        type=float,
        nargs="+",
        default=[0.5, 0.2, 0.1, 0.05, 0.01],
        help="a-priori bounds on min(eta, 1 - eta) for the Massart rows, in [0, 0.5]",
    )
    ap.add_argument("--delta", type=float, default=0.7, help="SPRT decision threshold (paper: delta_1 = 0.7)")
    ap.add_argument("--look-size", type=int, default=1, help="sequential scheme: samples between looks, >= 1")
    args = ap.parse_args(argv)
    try:
        lines = table(args.theta, args.gamma, args.rate_bounds, args.delta, args.look_size)
    except ValueError as e:
        print(f"uqdrive bound: {e}", file=sys.stderr)
        return 2
    print("\n".join(lines))
    return 0
