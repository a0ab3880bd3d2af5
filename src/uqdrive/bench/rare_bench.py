"""`uqdrive bench rare`: rollouts needed to refute "η1 ≥ 1 − 10⁻⁴ over a domain" when the true failure probability is
10⁻³, against plain Monte Carlo, on every world of the suite (`rare_suite`: the corner the importance sampler was
built for and the worlds it was not), each with its failure probability known exactly.

Same settings, budget (5,000 rollouts) and baseline for every world, γ = 0.05. Baseline: plain Monte Carlo with the
project's exact sequential Clopper–Pearson test (`ThresholdTest`, looks 5 % apart from 0.01/ε, its error computed
exactly): its expected rollouts depend on p alone, so one number serves every world. Methods: importance sampling
(IS), the defensive mixture with a cross-entropy proposal and the betting bound (`uqdrive.uq.rare`), a look at every
rollout; and where a world can be stepped and copied and scores the margin along a rollout, fixed splitting on that
margin with the same betting bound over trees (`uqdrive.uq.rare_splitting`). Each world's saving is its method's
(`method`: a rule fixed before any rollout from what the world declares: splitting where it applies, the exact test
itself where the margin is only the outcome, importance sampling elsewhere; the importance-sampling row is printed
for every world). A line shows plain Monte Carlo with the betting bound: the price of the test, not of a proposal.
Per world and method: E[rollouts] (a run that hits the budget counts the budget), P(refuted), the saving (the exact
test's E[rollouts] / the method's) and the error at the null boundary — the same world with its failure probability
put at exactly m = 10⁻⁴, every run to the budget, an error being a refutation at any look — with its Clopper–Pearson
95 % upper limit. Then the rollouts certifying η1 ≥ 1 − 10⁻⁴ with zero failures against the floor. Last line: RESULT
rare saving_min=… saving_median=… (over the worlds, each by its method) coverage_worst=<1 − the largest null error
of any row> error_cp_worst=<its upper limit> certify_rollouts_at_0=… certify_over_floor=….
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from scipy import stats

from uqdrive.bench.rare_suite import SuiteWorld, suite
from uqdrive.uq.rare import RareSettings, certification_test, floor_rollouts, refute, zero_failure_rollouts
from uqdrive.uq.rare_splitting import Splitting, refute_by_splitting
from uqdrive.uq.threshold import ThresholdTest

P_TRUE, EPS = 1e-3, 1e-4  # the true failure probability; the claim refuted is η1 ≥ 1 − ε
IS_BUDGET = 5_000  # importance sampling: most rollouts per run
MC_CAP = 2.0  # the exact test's last look, × 1/ε (20 × the 1/p a failure takes)
MC_BETTING_BUDGET = 20_000  # plain Monte Carlo with the betting bound: most rollouts per run (20 / p)
SPLITTING = Splitting((0.2, 0.4, 0.6, 0.8), 4)  # chosen on the walk world at p = 10⁻³ among 3-5 levels, ×3-5
MIXTURE = {"components": 16, "elite": 0.5, "memory": 50}  # chosen on the 16-mode world (docs/rare.md)
MIX_SEEDS = 1_000  # the mixture rows' seed indices start here, apart from the other rows'
CHUNK = 1_000  # runs simulated at once (the observations are runs × budget floats)
CERTIFY_BUDGET = 4  # certification: most rollouts, × the zero-failure floor (the test's later looks share γ)
LOOKS_FROM, LOOK_RATIO = 0.01, 1.05  # the exact test's looks: from 0.01/ε (at least 10) on, 5 % apart


def exact_looks(eps: float, ratio: float = LOOK_RATIO) -> tuple[int, ...]:
    """The exact test's looks: from 0.01/ε, each ``ratio`` × the last, to the cap."""
    looks, n, cap = [], max(10, round(LOOKS_FROM / eps)), round(MC_CAP / eps)
    while n < cap:
        looks.append(n)
        n = max(n + 1, math.ceil(n * ratio))
    return (*looks, cap)


def cp_upper(errors: int, runs: int) -> float:
    """The exact Clopper–Pearson 95 % (two-sided) upper limit of an error rate."""
    return float(stats.beta.ppf(0.975, errors + 1, runs - errors)) if errors < runs else 1.0


def splits(world: SuiteWorld) -> bool:
    """Whether the world can be stepped and copied and scores the margin along the rollout (splitting applies)."""
    return hasattr(world, "advance") and world.margin == "exact"


def method(world: SuiteWorld) -> str:
    """The method rule, fixed before any rollout from what the world declares: ``split`` where `splits`, plain
    Monte Carlo with the exact test (``MC``) where the margin is only the outcome (±1: nothing ranks rollouts
    before a failure, and after one the betting bound costs more than the exact test saves), else importance
    sampling (``IS``)."""
    return "split" if splits(world) else "MC" if world.margin == "outcome" else "IS"


def _refute(
    world: SuiteWorld,
    p: float,
    runs: int,
    seed: int,
    gamma: float,
    split: bool = False,
    adapt: bool = True,
    mixture: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """(rollouts, refuted) per run on ``world`` put at failure probability p: the default importance sampler,
    ``mixture``: its proposal a mixture (`MIXTURE`), ``split``: fixed splitting on the margin along the rollout;
    ``adapt`` False: plain Monte Carlo, betting."""
    settings = RareSettings(
        target=1 - EPS,
        gamma=gamma,
        refute_budget=IS_BUDGET if adapt else MC_BETTING_BUDGET,
        defensive=RareSettings.__dataclass_fields__["defensive"].default if adapt else 1.0,
        certify_budget=10**8,
        **(MIXTURE if mixture else {}),
    )
    placed, rng = world.at(p), np.random.default_rng(seed)
    rollouts, refuted = [], []
    for start in range(0, runs, CHUNK):
        size = min(CHUNK, runs - start)
        if split:
            run = refute_by_splitting(placed, placed.domain, settings, SPLITTING, rng, runs=size)
        else:
            keywords = {"seed": seed * 10**13 + start, "record_runs": 0, "adapt": adapt}
            run = refute(placed, placed.domain, settings, rng, runs=size, **keywords)
        rollouts.append(run.rollouts)
        refuted.append(run.refuted)
    return np.concatenate(rollouts), np.concatenate(refuted)


def _world_row(world: SuiteWorld, baseline: float, args: argparse.Namespace, index: int, how: str) -> tuple[float, int]:
    """Print one world's row for one method (``IS``, ``mix`` or ``split``); return (saving, false refutations at the
    null boundary)."""
    start = time.perf_counter()
    how_of = {"split": how == "split", "mixture": how == "mix"}
    rollouts, refuted = _refute(world, P_TRUE, args.runs, args.seed + 2 * index, args.gamma, **how_of)
    _, null = _refute(world, EPS, args.null_runs, args.seed + 2 * index + 1, args.gamma, **how_of)
    saving, errors = baseline / rollouts.mean(), int(null.sum())
    print(
        f"  {world.name:<36} {world.margin:>7} {how:>6} {rollouts.mean():>11.1f} {refuted.mean():>10.3f} "
        f"{saving:>7.1f} {errors / args.null_runs:>10.4f} {cp_upper(errors, args.null_runs):>8.4f} "
        f"{args.null_runs:>6}  {time.perf_counter() - start:.1f} s"
    )
    return saving, errors


def _certify_line(gamma: float) -> tuple[int, float]:
    budget = CERTIFY_BUDGET * floor_rollouts(1 - EPS, gamma)
    test = certification_test(RareSettings(target=1 - EPS, gamma=gamma, certify_budget=budget))
    zero, floor = zero_failure_rollouts(test), floor_rollouts(1 - EPS, gamma)
    print(
        f"certify eta1 >= 1 - {EPS:g}: {zero} rollouts with zero failures, {zero / floor:.2f} x the floor "
        f"ln(1/gamma)/ln(1/(1 - eps)) = {floor} that no black-box method beats; looks {test.looks}; "
        f"exact worst error {max(test.worst_errors()):.4f}"
    )
    return zero, zero / floor


def _suite_rows(
    baseline: float, refuted: float, exact: ThresholdTest, args: argparse.Namespace
) -> tuple[list[float], int, float]:
    """Print every world's rows; return the savings of each world's rule, the most false refutations of any row at
    the null boundary and the exact test's worst error where it was the rule's pick."""
    rows, errors, exact_worst = [], 0, 0.0
    for i, world in enumerate(suite()):
        hows = ("IS", *(("mix",) if args.mixture else ()), *(("split",) if splits(world) else ()))
        for how in hows:
            index = MIX_SEEDS + i if how == "mix" else 2 * i + (how == "split")  # the mix rows' own seeds
            saving, wrong = _world_row(world, baseline, args, index, how)
            errors = max(errors, wrong)
            if how == method(world):  # the rule's pick for this world: its saving counts
                rows.append(saving)
        if method(world) == "MC":  # the exact test's row: computed, its error exact
            print(
                f"  {world.name:<36} {world.margin:>7} {'MC':>6} {baseline:>11.1f} {refuted:>10.4f} {1.0:>7.1f} "
                f"{exact.worst_errors()[1]:>10.4f} {'exact':>8} {'-':>6}"
            )
            rows.append(1.0)
            exact_worst = max(exact_worst, exact.worst_errors()[1])
    return rows, errors, exact_worst


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench rare", description=__doc__)
    ap.add_argument("--runs", type=int, default=200, help="importance-sampling runs per world at p = 1e-3")
    ap.add_argument("--null-runs", type=int, default=2_000, help="runs per world at the null boundary p = 1e-4")
    ap.add_argument("--quick", action="store_true", help="20 runs and 50 null runs per world (a smoke test)")
    ap.add_argument("--gamma", type=float, default=0.05, help="allowed error of a refutation, in (0, 1)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the simulated runs")
    ap.add_argument(
        "--mixture", action="store_true", help="also a row per world for a 16-component mixture proposal (slow)"
    )
    ap.add_argument(
        "--look-ratio", type=float, default=LOOK_RATIO, help="exact test: each look this many times the last (> 1)"
    )
    args = ap.parse_args(argv)
    if args.quick:
        args.runs, args.null_runs = 20, 50
    for key, value, ok in (
        ("--look-ratio", args.look_ratio, args.look_ratio > 1),
        ("--runs", args.runs, args.runs >= 1),
        ("--null-runs", args.null_runs, args.null_runs >= 1),
        ("--gamma", args.gamma, 0 < args.gamma < 1),
    ):
        if not ok:
            ap.error(f"{key}={value} is out of range")
    exact = ThresholdTest(1 - EPS, args.gamma, exact_looks(EPS, args.look_ratio), theta=0.0, forced=False)
    _, refuted, mean_n = exact.operating_characteristics(np.array([1 - P_TRUE]))
    baseline = float(mean_n[0])
    print(
        f"refute eta1 >= 1 - {EPS:g} at true failure probability {P_TRUE:g} (gamma={args.gamma}), importance "
        f"sampling (budget {IS_BUDGET}) against plain MC with the exact sequential Clopper-Pearson test: "
        f"E[rollouts] {baseline:.1f}, P(refuted) {refuted[0]:.4f}, exact null error {exact.worst_errors()[1]:.4f}"
    )
    mc_rollouts, mc_refuted = _refute(suite()[0], P_TRUE, args.runs, args.seed + 99, args.gamma, adapt=False)
    print(
        f"plain MC with the betting bound (the importance sampler's test, a look every rollout, {args.runs} runs, "
        f"budget {MC_BETTING_BUDGET}; any world: it sees Bernoulli(p) outcomes): E[rollouts] {mc_rollouts.mean():.1f}"
        f", P(refuted) {mc_refuted.mean():.3f}, {baseline / mc_rollouts.mean():.2f} x the exact test's saving"
    )
    head = f"  {'world':<36} {'margin':>7} {'method':>6} {'E[rollouts]':>11} {'P(refuted)':>10} {'saving':>7}"
    print(f"{head} {'null error':>10} {'CP upper':>8} {'runs':>6}  time")
    rows, errors, exact_worst = _suite_rows(baseline, float(refuted[0]), exact, args)
    savings = np.array(rows)
    zero, ratio = _certify_line(args.gamma)
    print(
        f"RESULT rare saving_min={savings.min():.1f} saving_median={np.median(savings):.1f} "
        f"coverage_worst={1 - max(errors / args.null_runs, exact_worst):.4f} "
        f"error_cp_worst={cp_upper(errors, args.null_runs):.4f} "
        f"certify_rollouts_at_0={zero} certify_over_floor={ratio:.2f}"
    )
    return 0
