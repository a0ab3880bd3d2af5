"""`uqdrive bench train`: replicates trained per minute, R replicates stacked into one batch against the same R trained
one at a time (the same code with one replicate, as `python stages/train.py seed=r` runs), in one run, one thread.

Synthetic road frames (`uqdrive.data.synthetic`), so it runs without the pipeline's data; each method's sizes are a
profile's (conf/profile/<name>.yaml over conf/train.yaml, composed as the train stage composes them; `--override`
changes any, e.g. train.mcd.epochs=1). The head methods train on the MCD replicates the batched run trained. Then
where an MCD training step's time goes, per replicate: the batch (frames, labels, dropout uniforms), forward,
backward, optimiser, and an epoch's validation, at R = 1 and R. Ratios only compare numbers of this run.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from hydra import compose, initialize_config_dir

from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import FrameSet
from uqdrive.data.synthetic import synthetic_road_frames
from uqdrive.models.checkpoint import save_posterior
from uqdrive.models.diagnostics import function_space_diagnostics
from uqdrive.models.mcd import MCDPosterior, StackedMCD
from uqdrive.models.metrics import classification_metrics
from uqdrive.models.pilotnet import Architecture, init_weights
from uqdrive.models.posterior import Fitted, Posterior, posterior_settings
from uqdrive.models.schemas import register_schemas
from uqdrive.models.stacking import adam, epoch_batches, stacked_features
from uqdrive.models.train_plan import TrainStage
from uqdrive.models.training import TrainingData, evaluate
from uqdrive.resolvers import register_resolvers
from uqdrive.schema import validate

CONF = Path(__file__).resolve().parents[3] / "conf"
METHODS = ("mcd", "vi", "hmc", "ensemble", "laplace")  # mcd first: the heads build on its replicates
STEP_PARTS = ("batch", "forward", "backward", "optimiser")
WARMUP_STEPS = 3


@dataclass(frozen=True)
class Method:
    """A method as the train stage composes it: its class, settings and what its `TrainingData` needs."""

    cls: type[Posterior]
    settings: Any
    arch: Architecture
    bins: SteeringBins
    eval_samples: int


def composed_methods(profile: str, experiment: str, methods: list[str], overrides: list[str]) -> dict[str, Method]:
    register_resolvers()
    register_schemas()
    composed = {}
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        for method in methods:
            cfg = compose(
                "train",
                [f"profile={profile}", f"experiment={experiment}", f"model={method}", "paths.root=/unused", *overrides],
            )
            stage = validate(TrainStage, cfg)
            cls, settings = posterior_settings(stage.model)
            composed[method] = Method(cls, settings, stage.arch, stage.experiment.bins, stage.train.eval_samples)
    return composed


def warm_up() -> None:
    """Pay here the one-off costs a process's first fit pays (seconds each: torch._dynamo's import on the first
    optimiser step, torchmetrics' on the first validation, ArviZ's on HMC's first diagnostics), not in whichever mode
    is timed first."""
    parameter = torch.zeros(1, requires_grad=True)
    parameter.grad = torch.zeros(1)
    adam([parameter], 1e-3).step()
    classification_metrics(torch.full((2, 2), 0.5), torch.tensor([0, 1]))
    function_space_diagnostics(torch.full((2, 4, 1, 2), 0.5))


def synthetic_split(count: int, seed: int, bins: SteeringBins) -> FrameSet:
    images, steer = synthetic_road_frames(count, np.random.default_rng(seed))
    labels = torch.from_numpy(np.asarray(bins.to_class(steer), dtype=np.int64))
    return FrameSet(torch.from_numpy(images), labels, bins.num_classes, name=f"synthetic{seed}")


def timed(run: Callable[[], Any]) -> tuple[float, Any]:
    started = time.perf_counter()
    result = run()
    return time.perf_counter() - started, result


def method_times(
    method: Method, frames: tuple[FrameSet, FrameSet], bases: Path, seeds: list[int], repeats: int
) -> tuple[float, float, list[Fitted], list[Fitted]]:
    """Seconds to train the replicates one at a time and stacked (the least of ``repeats`` runs each, in alternating
    order: the first run of a shape pays oneDNN's kernel set-up), and the last runs' fits. Fresh `TrainingData`
    each run, so either pays for its trunk features as the stage does."""

    def data(seed: int) -> TrainingData:
        return TrainingData(*frames, method.bins, method.arch, bases / f"seed{seed}.pt", method.eval_samples)

    def fit(chosen: list[int]) -> list[Fitted]:
        generators = [torch.Generator().manual_seed(s) for s in chosen]
        return method.cls.fit_replicates(method.settings, [data(s) for s in chosen], generators)

    def one_at_a_time() -> tuple[float, list[Fitted]]:
        runs = [timed(lambda s=s: fit([s])) for s in seeds]
        return sum(t for t, _ in runs), [f for _, fits in runs for f in fits]

    alone_s, stacked_s = float("inf"), float("inf")
    for repeat in range(repeats):
        for mode in ("alone", "stacked") if repeat % 2 == 0 else ("stacked", "alone"):
            if mode == "alone":
                seconds, alone = one_at_a_time()
                alone_s = min(alone_s, seconds)
            else:
                seconds, stacked = timed(lambda: fit(seeds))
                stacked_s = min(stacked_s, seconds)
    return alone_s, stacked_s, alone, stacked


def step_breakdown(method: Method, train: FrameSet, val: FrameSet, replicates: int, steps: int) -> dict[str, float]:
    """ms per replicate of each part of an MCD training step (mean over ``steps`` steps) and of an epoch's
    validation (stacked trunk features, then each replicate's head draws)."""
    settings = method.settings
    generators = [torch.Generator().manual_seed(r) for r in range(replicates)]
    networks = [MCDPosterior(method.arch, method.bins, settings.init_p, settings.temperature) for _ in generators]
    stacked = StackedMCD([init_weights(n, g) for n, g in zip(networks, generators)])
    optimizer = adam(stacked.parameters(), settings.lr)
    seconds = dict.fromkeys(STEP_PARTS, 0.0)
    done = -WARMUP_STEPS  # untimed: the first steps of a shape pay oneDNN's kernel set-up
    while done < steps:
        for index in epoch_batches(len(train), settings.batch_size, generators):
            marks = [time.perf_counter()]
            batch = stacked.batch(train, index, generators)
            marks.append(time.perf_counter())
            losses = stacked.losses(*batch, len(train), settings.lengthscale)
            marks.append(time.perf_counter())
            optimizer.zero_grad()
            losses.sum().backward()
            marks.append(time.perf_counter())
            optimizer.step()
            marks.append(time.perf_counter())
            for part, start, end in zip(STEP_PARTS, marks, marks[1:]):
                seconds[part] += (end - start) * (done >= 0)
            done += 1
            if done == steps:
                break
    per_step = {part: 1e3 * s / (steps * replicates) for part, s in seconds.items()}

    def validation() -> None:
        features = stacked_features(stacked.template.trunk, stacked.params, val)
        for network, f, g in zip(stacked.networks_now(), features, generators):
            evaluate(network, f, val.labels, method.eval_samples, g)

    return {**per_step, "validation": 1e3 * timed(validation)[0] / replicates}


def mean_accuracy(fits: list[Fitted]) -> float:
    return float(np.mean([f.curve[-1]["val_accuracy"] for f in fits]))


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench train", description=__doc__)
    ap.add_argument("--replicates", type=int, default=8, help="R: training seeds 0..R-1")
    ap.add_argument("--profile", default="tiny", help="conf/profile/ whose training sizes to use")
    ap.add_argument("--experiment", default="offline", help="conf/experiment/: its steering classes")
    ap.add_argument("--train-frames", type=int, default=640, help="synthetic training frames")
    ap.add_argument("--val-frames", type=int, default=240, help="synthetic validation frames")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS, help="mcd always trains first")
    ap.add_argument("--override", action="append", default=[], help="Hydra override of the train config")
    ap.add_argument("--repeats", type=int, default=2, help="runs of each mode per method; the fastest counts")
    ap.add_argument("--steps", type=int, default=20, help="MCD steps timed part by part at R = 1 and R")
    args = ap.parse_args(argv)
    if args.replicates < 2 or args.steps < 1 or args.repeats < 1:
        ap.error(f"--replicates={args.replicates} must be >= 2, --steps={args.steps} and --repeats={args.repeats} >= 1")
    torch.set_num_threads(1)
    warm_up()
    methods = composed_methods(
        args.profile, args.experiment, ["mcd", *(m for m in args.methods if m != "mcd")], args.override
    )
    bins = methods["mcd"].bins
    frames = synthetic_split(args.train_frames, 1, bins), synthetic_split(args.val_frames, 2, bins)
    seeds = list(range(args.replicates))
    print(
        f"R={args.replicates} replicates, profile {args.profile}, {args.train_frames} train / {args.val_frames} val "
        f"synthetic frames, 1 thread; seconds for all R (fastest of {args.repeats}), one at a time against stacked"
    )
    print(f"{'method':>8} {'one_at_a_time_s':>15} {'stacked_s':>9} {'speedup':>7} {'val_acc_alone':>13} {'stacked':>7}")
    totals, speedups = [0.0, 0.0], {}
    with tempfile.TemporaryDirectory() as folder:
        for name in METHODS:
            if name not in methods:
                continue
            alone_s, stacked_s, alone, stacked = method_times(methods[name], frames, Path(folder), seeds, args.repeats)
            if name == "mcd":  # the heads' trunks
                for seed, fit in zip(seeds, stacked):
                    save_posterior(fit.posterior, Path(folder) / f"seed{seed}.pt")
            if name in args.methods:
                totals = [totals[0] + alone_s, totals[1] + stacked_s]
                speedups[name] = alone_s / stacked_s
                print(
                    f"{name:>8} {alone_s:>15.2f} {stacked_s:>9.2f} {speedups[name]:>7.2f} "
                    f"{mean_accuracy(alone):>13.3f} {mean_accuracy(stacked):>7.3f}"
                )
    print(f"{'all':>8} {totals[0]:>15.2f} {totals[1]:>9.2f} {totals[0] / totals[1]:>7.2f}")
    per_minute = [60 * args.replicates / t for t in totals]
    print(f"replicates per minute (every method above): one at a time {per_minute[0]:.2f}, stacked {per_minute[1]:.2f}")
    print(f"MCD step, ms per replicate ({args.steps} steps of batch {methods['mcd'].settings.batch_size}):")
    print(f"{'R':>3} " + " ".join(f"{part:>10}" for part in (*STEP_PARTS, "step", "validation")))
    steps = {}
    for replicates in (1, args.replicates):
        parts = step_breakdown(methods["mcd"], *frames, replicates, args.steps)
        steps[replicates] = sum(parts[p] for p in STEP_PARTS)
        row = [*(parts[p] for p in STEP_PARTS), steps[replicates], parts["validation"]]
        print(f"{replicates:>3} " + " ".join(f"{value:>10.2f}" for value in row))
    ratios = " ".join(f"{name}={ratio:.2f}" for name, ratio in speedups.items())
    print(
        f"RESULT train batched_speedup={totals[0] / totals[1]:.2f} {ratios} "
        f"mcd_step_speedup={steps[1] / steps[args.replicates]:.2f} replicates_per_min={per_minute[1]:.2f}"
    )
    return 0
