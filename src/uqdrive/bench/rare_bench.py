"""`uqdrive bench rare`: rollouts needed to refute "η1 ≥ target over a domain" by importance sampling against plain
Monte Carlo, on a synthetic world whose failure probability over the domain is known exactly (`rare_world`).

Cases: refute η1 ≥ 1 − 10⁻⁴ when the true failure probability is 10⁻³, and η1 ≥ 1 − 10⁻⁵ when it is 10⁻⁴, all
at γ = 0.05 with the same optional stopping treatment — a look at every rollout for the betting bounds, and for
exact Clopper–Pearson the project's sequential threshold test, calibrated by exact computation over its looks
(×1.05 apart) so that stopping at any of them keeps its error ≤ γ. Importance sampling: the defensive mixture with
a cross-entropy proposal and the betting bound (`uqdrive.uq.rare`). Monte Carlo: the exact sequential test
(E[n] exact) and the same betting bound on nominal draws (simulated); the saving is against the better of the two
and for the default settings (a second importance-sampling row, rounds of 20, shows one knob's effect).
Each design's error at the null boundary (true failure probability = 1 − target) is printed beside it: exact for
the exact test, simulated for the others. Then the rollouts certifying η1 ≥ 1 − 10⁻⁴ with zero failures. Last
line: RESULT rare refute_saving_1e3=… refute_saving_1e4=… (Monte Carlo rollouts / importance sampling's)
certify_rollouts_at_0=… coverage_1e3=<design>:<1 − error at the null boundary>,… coverage_1e4=….
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from uqdrive.bench.rare_world import DOMAIN, CornerWorld
from uqdrive.uq.rare import RareSettings, certification_test, floor_rollouts, refute, zero_failure_rollouts
from uqdrive.uq.threshold import ThresholdTest

CASES = ((1e-3, 1e-4), (1e-4, 1e-5))  # (true failure probability, ε = 1 − target)
IS_BUDGET = 5_000  # importance sampling: most rollouts per run
MC_CAP = 2.0  # Monte Carlo: most rollouts per run, × 1/ε (20 × the 1/p a failure takes)
IS_DEFAULT = "IS cross-entropy + betting"  # the default settings: the RESULT's saving is theirs
LONG_ROUNDS = 20  # a second importance-sampling row: longer rounds run more in parallel but adapt later
SHORT = {  # a design's name in the RESULT line's coverage fields
    "MC exact sequential Clopper-Pearson": "mc_exact",
    "MC betting bound": "mc_betting",
    IS_DEFAULT: "is",
    f"IS, rounds of {LONG_ROUNDS} (not the default)": f"is_rounds{LONG_ROUNDS}",
}
CERTIFY_BUDGET = 4  # certification: most rollouts, × the zero-failure floor (the test's later looks share γ)
LOOKS_FROM, LOOK_RATIO = 0.01, 1.05  # the exact test's looks: from 0.01/ε (at least 10) on, 5 % apart


def exact_looks(eps: float, ratio: float = LOOK_RATIO) -> tuple[int, ...]:
    """The exact test's looks: from 0.01/ε, each ``ratio`` × the last, to the cap."""
    looks, n, cap = [], max(10, round(LOOKS_FROM / eps)), round(MC_CAP / eps)
    while n < cap:
        looks.append(n)
        n = max(n + 1, math.ceil(n * ratio))
    return (*looks, cap)


def _simulated(p: float, eps: float, runs: int, seed: int, round_size: int | None) -> tuple[float, float, float]:
    """(mean rollouts, share refuted, error at the null boundary) of a betting design: plain Monte Carlo where
    ``round_size`` is None, else importance sampling with rounds of that many rollouts."""
    monte_carlo = round_size is None
    if monte_carlo:
        budget = round(MC_CAP / eps)
        settings = RareSettings(
            target=1 - eps, defensive=1.0, refute_budget=budget, round_size=1_000, certify_budget=10**8
        )
    else:
        settings = RareSettings(target=1 - eps, refute_budget=IS_BUDGET, round_size=round_size, certify_budget=10**8)
    rng, keywords = np.random.default_rng(seed), {"adapt": not monte_carlo, "record_runs": 0}
    run = refute(CornerWorld.at(p, DOMAIN), DOMAIN, settings, rng, runs=runs, **keywords)
    null = refute(CornerWorld.at(eps, DOMAIN), DOMAIN, settings, rng, runs=runs, seed=10**12, **keywords)
    return float(run.rollouts.mean()), float(run.refuted.mean()), float(null.refuted.mean())


def _designs(args: argparse.Namespace) -> tuple[tuple[str, int, int | None], ...]:
    """The simulated designs: (name, runs, rounds of importance sampling; None: plain Monte Carlo)."""
    default = RareSettings.__dataclass_fields__["round_size"].default
    return (
        ("MC betting bound", args.mc_runs, None),
        (IS_DEFAULT, args.runs, default),
        (f"IS, rounds of {LONG_ROUNDS} (not the default)", args.runs, LONG_ROUNDS),
    )


def _case(p: float, eps: float, args: argparse.Namespace) -> tuple[float, str]:
    """Print one case's designs; return the saving (better Monte Carlo's rollouts / importance sampling's) and
    each design's coverage at the null boundary, as RESULT fields."""
    start = time.perf_counter()
    exact = ThresholdTest(1 - eps, args.gamma, exact_looks(eps, args.look_ratio), theta=0.0, forced=False)
    _, refuted, mean_n = exact.operating_characteristics(np.array([1 - p]))
    exact_error = exact.worst_errors()[1]
    built = time.perf_counter() - start
    rows = {
        "MC exact sequential Clopper-Pearson": (mean_n[0], refuted[0], exact_error, "exact", built),
    }
    for name, runs, rounds in _designs(args):
        start = time.perf_counter()
        mean, share, error = _simulated(p, eps, runs, args.seed, rounds)
        rows[name] = (mean, share, error, f"{runs} runs", time.perf_counter() - start)
    print(f"refute eta1 >= 1 - {eps:g} at true failure probability {p:g} (gamma={args.gamma}):")
    print(f"  {'design':<36} {'E[rollouts]':>11} {'P(refuted)':>10} {'null error':>10} {'coverage':>8}  how")
    for name, (mean, share, error, how, seconds) in rows.items():
        print(f"  {name:<36} {mean:>11.1f} {share:>10.4f} {error:>10.4f} {1 - error:>8.4f}  {how}, {seconds:.1f} s")
    monte_carlo = min(rows["MC exact sequential Clopper-Pearson"][0], rows["MC betting bound"][0])
    coverage = ",".join(f"{SHORT[name]}:{1 - error:.4f}" for name, (_, _, error, _, _) in rows.items())
    return monte_carlo / rows[IS_DEFAULT][0], coverage


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench rare", description=__doc__)
    ap.add_argument("--runs", type=int, default=1_000, help="importance-sampling runs per case (and at the null)")
    ap.add_argument("--mc-runs", type=int, default=100, help="Monte Carlo betting runs per case (and at the null)")
    ap.add_argument("--gamma", type=float, default=0.05, help="allowed error of a refutation, in (0, 1)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the simulated runs")
    ap.add_argument(
        "--look-ratio", type=float, default=LOOK_RATIO, help="exact test: each look this many times the last (> 1)"
    )
    args = ap.parse_args(argv)
    if not args.look_ratio > 1:
        ap.error(f"--look-ratio={args.look_ratio} must be > 1")
    (saving_3, coverage_3), (saving_4, coverage_4) = (_case(p, eps, args) for p, eps in CASES)
    zero = {}
    for _, eps in CASES[:1]:  # the floor scales as 1/ε: 10⁻⁵ needs ten times the rollouts of 10⁻⁴
        budget = CERTIFY_BUDGET * floor_rollouts(1 - eps, args.gamma)
        settings = RareSettings(target=1 - eps, gamma=args.gamma, certify_budget=budget)
        test = certification_test(settings)
        zero[eps] = zero_failure_rollouts(test)
        print(
            f"certify eta1 >= 1 - {eps:g}: {zero[eps]} rollouts with zero failures (ln(1/gamma)/eps = "
            f"{math.log(1 / args.gamma) / eps:.0f}), looks {test.looks}; "
            f"exact worst error {max(test.worst_errors()):.4f}"
        )
    print(
        f"RESULT rare refute_saving_1e3={saving_3:.1f} refute_saving_1e4={saving_4:.1f} "
        f"certify_rollouts_at_0={zero[CASES[0][1]]} coverage_1e3={coverage_3} coverage_1e4={coverage_4}"
    )
    return 0
