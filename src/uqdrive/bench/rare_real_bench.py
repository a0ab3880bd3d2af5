"""`uqdrive bench rare_real`: rollouts needed to refute "η1 ≥ 1 − ε over an operating domain" for a trained
controller in the pybullet world, by the rare stage (importance sampling, the betting bound) and by plain Monte
Carlo with the exact sequential test, on a domain whose failure probability a pilot states with its interval.

The domain: sensor noise uniform on [0, --noise-high], the weather a blend from clear noon (0, the training
condition) to rain (1) drawn from Beta(--shape); failures are rare when the blend's upper tail barely reaches the
rain where this controller leaves its lane. One stream of rollouts from the domain (seed --mc-seed + i) serves the
pilot and Monte Carlo: the pilot is its first --pilot rollouts, a size fixed in advance (Clopper–Pearson 95 % on
the failure probability p), and the exact sequential Clopper–Pearson test (`ThresholdTest`, looks 5 % apart from
0.01/ε, the bench's) reads the same stream in order and stops where it refutes, so each is valid on its own. The
rare stage (`run_rare`, conf/rare.yaml) then runs on seeds of its own (rare.base_seed). The models are the
project's at --root (`dvc repro train@offline-vi` trains quick-profile VI). Last line: RESULT rare_real
p_pilot=… p_low=… p_high=… mc_rollouts=… mc_refuted=… is_rollouts=… is_refuted=… saving=… (Monte Carlo's
rollouts / the rare stage's; one run of each: a measurement on this world, not an expectation).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir

from uqdrive.bench.rare_bench import EPS, exact_looks
from uqdrive.envelope.domain import Domain
from uqdrive.envelope.plan import build_envelope
from uqdrive.models.schemas import register_schemas as register_models
from uqdrive.pipeline.rare_stage import describe, rare_cell, run_rare
from uqdrive.policy.warnings import register_schema as register_warning
from uqdrive.safety.runner import CellRunner
from uqdrive.sim.config import register_schemas as register_world
from uqdrive.uq.bounds import clopper_pearson_interval
from uqdrive.uq.threshold import ThresholdTest


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="uqdrive bench rare_real", description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", default=".", help="the project whose models drive (default: here)")
    parser.add_argument("--model", default="vi", help="the posterior that drives (conf/model/)")
    parser.add_argument("--seed", type=int, default=0, help="the training replicate")
    parser.add_argument("--profile", default="quick", help="the profile the models were trained on")
    parser.add_argument("--shape", type=float, nargs=2, default=(1.0, 2.8), help="Beta(a, b) of the blend")
    parser.add_argument("--noise-high", type=float, default=0.02, help="sensor noise uniform on [0, this]")
    parser.add_argument("--pilot", type=int, default=3000, help="the pilot's rollouts (fixed in advance)")
    parser.add_argument("--mc-seed", type=int, default=600_000, help="the Monte Carlo stream's first rollout seed")
    parser.add_argument("--mc-cap", type=int, default=None, help="the test's last look (default 2/ε)")
    parser.add_argument("--gamma", type=float, default=0.05, help="each refutation's error")
    parser.add_argument("--skip-is", action="store_true", help="the pilot and Monte Carlo only")
    parser.add_argument("overrides", nargs="*", help="more Hydra overrides of conf/rare.yaml")
    return parser.parse_args(argv)


def overrides(args: argparse.Namespace) -> list[str]:
    a, b = args.shape
    return [
        f"model={args.model}",
        f"seed={args.seed}",
        f"profile={args.profile}",
        f"paths.root={Path(args.root).resolve()}",
        "progress=false",
        f"envelope.axes=[{{key:noise,range:[0.0,{args.noise_high}]}},{{key:weather.blend,range:[0.0,1.0]}}]",
        f"rare.shapes={{weather.blend:[{a},{b}]}}",
        f"rare.target={1 - EPS}",
        f"rare.gamma={args.gamma}",
        *args.overrides,
    ]


def monte_carlo(cfg, args: argparse.Namespace) -> tuple[np.ndarray, int, bool]:
    """The stream's outcomes (1: safe) up to max(pilot, the test's stop), the test's rollouts and whether it
    refuted."""
    envelope = build_envelope(cfg)
    domain = Domain.over(envelope.space, dict(cfg.rare.shapes))
    rng, cells, outcomes = np.random.default_rng(args.mc_seed), [], []
    log_dir = Path(cfg.paths.root) / "cache/rollouts/rare_real" / f"{args.model}-seed{args.seed}-{args.mc_seed}"
    with CellRunner.of(envelope.stage.executor, envelope.stage.progress) as runner:

        def draw(m: int) -> np.ndarray:
            start = args.mc_seed + sum(map(len, outcomes))
            safe, _ = rare_cell(envelope, log_dir, runner, cells, domain.sample(rng, m), start)
            outcomes.append(safe)
            return safe

        cap = args.mc_cap or exact_looks(EPS)[-1]
        looks = (*(n for n in exact_looks(EPS) if n < cap), cap)  # a smaller cap: a test of its own, as exact
        test = ThresholdTest(1 - EPS, args.gamma, looks, theta=0.0, forced=False)
        decision = test.run(draw)
        drawn = sum(map(len, outcomes))
        if drawn < args.pilot:
            draw(args.pilot - drawn)
    return np.concatenate(outcomes), decision.n, decision.decision == "below"


def main(argv: list[str]) -> int:
    args = parse(argv)
    for register in (register_world, register_warning, register_models):  # the config groups' schemas, as a stage
        register()
    with initialize_config_dir(config_dir=str(Path(args.root).resolve() / "conf"), version_base="1.3"):
        cfg = compose("rare", overrides=overrides(args))
    start = time.perf_counter()
    outcomes, mc_rollouts, mc_refuted = monte_carlo(cfg, args)
    failures = int((outcomes[: args.pilot] == 0).sum())
    low, high = map(float, clopper_pearson_interval(failures, args.pilot, 0.05))  # 95 % on p
    p = failures / args.pilot
    print(f"pilot: {failures} failures in {args.pilot} rollouts: p = {p:.2g}, 95 % [{low:.2g}, {high:.2g}]")
    verdict = "refuted" if mc_refuted else "not refuted"
    seconds = time.perf_counter() - start
    print(f"Monte Carlo, exact sequential test: {verdict} after {mc_rollouts} rollouts ({seconds:.0f} s)")
    is_rollouts, is_refuted = 0, False
    if not args.skip_is:
        run = run_rare(cfg)
        print(describe(run))
        is_rollouts, is_refuted = run.result.refute_rollouts, run.result.refuted
    saving = mc_rollouts / is_rollouts if is_rollouts else float("nan")
    print(
        f"RESULT rare_real p_pilot={p:.2g} p_low={low:.2g} p_high={high:.2g} mc_rollouts={mc_rollouts} "
        f"mc_refuted={int(mc_refuted)} is_rollouts={is_rollouts} is_refuted={int(is_refuted)} saving={saving:.2f}"
    )
    return 0
