"""The `acquire` stage: DAgger rounds for one controller (method × replicate), aimed where the previous safety sweep
found it unsafe. A round drives the current controller (with probability β per step the expert instead, β decaying)
at the training condition and at every condition the sweep flagged (the upper end of η1's interval below
``acquire.target``), labels every visited frame with the expert's command in that state
(`uqdrive.acquire.acquisition`), adds the frames to all earlier ones and retrains with the train stage's own
functions; then η̂1 of the new controller at the check cells, beside the expert's own η̂1 on the same seeds.

Round 0 is the behaviour-cloned controller the train stage made (`safety.model_path`); ``acquire.rounds=0`` only
checks it. Each round's files sit in a folder of its own (``acquire.out_dir``/round<k>) with its record, so an
interrupted stage resumes at the first round without one for the same settings. The controller the rounds end with
is copied to ``acquire.out_dir``/controller.pt, at a path that does not depend on the round count, for the stages
that drive it further (conf/gym_avoid_acquired.yaml).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import mlflow
import pyarrow as pa
from omegaconf import DictConfig, OmegaConf

from uqdrive.acquire.acquisition import (
    AcquiredAt,
    Acquisition,
    AcquisitionCheck,
    RoundRecord,
    RoundSummary,
    acquire_episodes,
    before_after,
    expert_job,
    flagged_cells,
)
from uqdrive.acquire.plan import AcquireStage, Rounds, Where
from uqdrive.data.binning import SteeringBins
from uqdrive.data.frames import encode_png
from uqdrive.data.preprocess import Split, preprocess_raw
from uqdrive.data.tables import PROCESSED_SCHEMA, RAW_SCHEMA, read_table, write_table_batches
from uqdrive.deps import file_digest
from uqdrive.models.checkpoint import read_checkpoint, save_posterior
from uqdrive.pipeline.safety_stage import plan_cell, reusable_result, safety_cell
from uqdrive.pipeline.train_stage import TrainStage, fit
from uqdrive.policy.references import ExpertPolicy
from uqdrive.records import read_record, write_record
from uqdrive.resolvers import world_location
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.safety.executors import WorkerEnvs
from uqdrive.safety.plan import SafetyStage
from uqdrive.safety.runner import CellRunner, code_digest, estimate_key
from uqdrive.schema import ConfigError, validate
from uqdrive.stage import compose_cell
from uqdrive.tracking import stage_run
from uqdrive.uq import Estimate

CONTROLLER = "controller.pt"  # in acquire.out_dir: the last round's controller (no rounds: the behaviour-cloned one)
TRAIN_KEYS = {"experiment", "model", "seed", "profile", "outputs", "paths", "progress", "train", "arch", "tracking"}
"""The overrides of the stage's command line a retraining's `train` config takes (the rest are the rollouts')."""


def as_swept(stage: AcquireStage, where: Where) -> Where:
    """``where`` as the sweep named it: a Gymnasium world as collected is its axis' first location (the convention
    of the world's own axis, gym_world.axis), so the training cell pairs with the sweep's own cell there."""
    world, axis = stage.gym_world, stage.acquire.world_axis
    if world is None or axis is None or where.location != world.name:
        return where
    return Where(world_location(world.name, next(iter(axis.values))), where.weather, where.noise)


def targeted_conditions(training: Where, flagged: Sequence[SafetyCell]) -> list[Where]:
    """Where a round's rollouts drive: the training condition, then each condition the sweep flagged, once each."""
    wheres = [training, *(Where(c.location, c.weather, c.noise) for c in flagged)]
    return list({w.label: w for w in wheres}.values())


def sweep_cells(stage: AcquireStage) -> list[SafetyCell]:
    """This controller's cells of the previous sweep; none is an error naming the folder and the stage to run."""
    folder, method = Path(stage.acquire.cells_dir), stage.model["name"]
    paths = sorted(folder.glob(f"{method}-{stage.replicate}-*.json"))
    cells = [read_record(SafetyCell, p, "safety") for p in paths]
    cells = [c for c in cells if (c.method, c.replicate, c.experiment) == (method, stage.seed, stage.experiment.name)]
    if not cells:
        raise ConfigError(
            f"acquire.cells_dir={folder}: no safety cell of {stage.experiment.name} {method} {stage.replicate}; "
            "run the safety sweep first (dvc repro safety)"
        )
    return cells


def rounds_key(cfg: DictConfig, model: Path) -> str:
    """What every round depends on: the stage's settings (less the round count and the progress bars), the
    behaviour-cloned model's bytes and the code a round runs."""
    settings = OmegaConf.to_container(cfg, resolve=True)
    settings["acquire"].pop("rounds")
    for key in ("check_seed", "check_theta"):  # checks are cells of their own, reused by their identity
        settings["acquire"].pop(key)
    settings.pop("progress", None)
    code = code_digest([__name__])
    identity = json.dumps(
        {"settings": settings, "model": file_digest(model), "code": code}, sort_keys=True, default=str
    )
    return hashlib.sha256(identity.encode()).hexdigest()[:16]


def acquire_at(ctx: Rounds, k: int, index: int, where: Where, model: Path, beta: float) -> pa.Table:
    """Round ``k``'s episodes at condition ``index`` (``where``), labelled by the expert, as raw rows."""
    stage, section = ctx.stage, ctx.stage.acquire
    plan = plan_cell(ctx.safety_config(where, model))
    job, block = plan.job, stage.rollout_seeds(section.base_seed)
    first = block + ((k - 1) * len(ctx.conditions) + index) * section.episodes
    seeds = list(range(first, first + section.episodes))
    envs = WorkerEnvs(job, 1)
    try:
        learner, expert = job.policy.build(job.control_hz), ExpertPolicy(plan.stage.autopilot)
        episodes = acquire_episodes(envs.first(1), learner, expert, beta, seeds, job.where, encode_png)
    finally:
        envs.close()
    tables = []
    for seed, rows in zip(seeds, episodes):
        n = len(rows["step"])
        where_columns = {"scenario": [job.where.location] * n, "weather": [job.where.weather_name] * n}
        ids = {"noise": [job.where.noise] * n, "episode": [seed - block] * n, "seed": [seed] * n}
        tables.append(pa.Table.from_pydict({**where_columns, **ids, **rows}, schema=RAW_SCHEMA))
    return pa.concat_tables(tables)


def aggregate(raw: pa.Table, previous: Path, folder: Path, bins: SteeringBins) -> int:
    """The previous round's training frames and ``raw``'s, binned as preprocess bins them (every acquired frame
    trains: the validation frames stay the collection's, so accuracy compares across rounds), written with the
    validation split into ``folder``; returns the training frames."""
    acquired = preprocess_raw(raw, bins, Split(val_fraction=0.0))[0] if raw.num_rows else None
    train = read_table(previous / "train.parquet", PROCESSED_SCHEMA)
    train = pa.concat_tables([train, acquired]) if acquired is not None else train
    folder.mkdir(parents=True, exist_ok=True)
    write_table_batches(folder / "train.parquet", PROCESSED_SCHEMA, [train.to_pydict()])
    shutil.copyfile(previous / "val.parquet", folder / "val.parquet")
    return train.num_rows


def retrain(train_overrides: Sequence[str], method: str, processed: Path, models: Path) -> tuple[Path, float]:
    """``method``'s controller retrained on ``processed`` by the train stage's own `fit` and config (a head on an
    MCD trunk retrained first on the same frames); its file and validation accuracy."""
    trunk, accuracy = None, float("nan")
    for name in ("mcd",) if method == "mcd" else ("mcd", method):
        cell = {"model": name, "paths.processed": str(processed), **({"train.base_model": str(trunk)} if trunk else {})}
        stage = validate(TrainStage, compose_cell("train", train_overrides, cell))
        (result,) = fit([stage])
        metrics = {f"val_{k}": v for k, v in result.scores.items()}
        trunk = save_posterior(result.fitted.posterior, models / name / f"{stage.replicate}.pt", {"metrics": metrics})
        accuracy = result.scores["accuracy"]
    return trunk, accuracy


def check(ctx: Rounds, k: int, model: Path) -> list[AcquisitionCheck]:
    """η̂1 of ``model`` at every check cell, by the safety cell's estimator, beside the expert's. Where rounds are
    compared, every round drives the same fresh seeds (``acquire.check_seed``; ``acquire.check_theta``: as many as
    that θ needs): the sweep flagged its cells by their outcomes on its own seeds, so a comparison on those would
    favour a gain wherever the sweep was unlucky. A cell is read back where a record with its identity exists: its
    own, or (no rounds: the behaviour-cloned controller alone, compared with nothing) the sweep's cell there."""
    rows, stage, section = [], ctx.stage, ctx.stage.acquire
    fresh = {"safety.base_seed": section.check_seed} if section.rounds else {}
    if section.rounds and section.check_theta is not None:
        fresh["safety.theta"] = section.check_theta
    for where in ctx.checks:
        out = ctx.folder(k) / "check" / where.label
        plan = plan_cell(ctx.safety_config(where, model, **{"safety.rollout_log": f"{out}.jsonl"}, **fresh))
        swept = Path(stage.acquire.cells_dir) / f"{stage.model['name']}-{stage.replicate}-{where.label}.json"
        cell = reusable_result(f"{out}.json", plan.key) or (reusable_result(swept, plan.key) if k == 0 else None)
        if cell is None:
            name = f"acquire round {k} {where.label}"
            run = ctx.runner.estimate(name, plan.job, plan.stage.estimator, plan.key, f"{out}.jsonl")
            cell = safety_cell(plan, run)
            write_record(f"{out}.json", cell)
        expert = ctx.expert.get(where.label) or expert_estimate(ctx, plan, where)
        ctx.expert[where.label] = expert
        est = cell.estimate
        rows.append(
            AcquisitionCheck(
                stage.model["name"], stage.seed, k, where.label, est.value, est.low, est.high, est.n,
                expert.value, expert.low, expert.high, cell.outcomes,
            )
        )  # fmt: skip
    return rows


def expert_estimate(ctx: Rounds, plan: Any, where: Where) -> Estimate:
    """The expert's η̂1 at a check cell: the cell's job and estimator, the expert driving (its log, shared by the
    replicate's methods, replays a rerun and the other methods' identical cells)."""
    job = expert_job(plan.job, plan.stage.autopilot)
    key = estimate_key(job, plan.stage.estimator, __name__)
    log = Path(ctx.stage.acquire.expert_logs) / f"{where.label}.jsonl"
    return ctx.runner.estimate(f"expert {where.label}", job, plan.stage.estimator, key, log).outcome


def reused_round(ctx: Rounds, k: int) -> RoundRecord | None:
    """Round ``k``'s record if it finished with these settings and its controller is on disk."""
    try:
        done = read_record(RoundRecord, ctx.folder(k) / "round.json", "acquire")
    except (FileNotFoundError, ConfigError):
        return None
    return done if done.config_hash == ctx.key and Path(done.model).exists() else None


def rechecked(ctx: Rounds, k: int, done: RoundRecord) -> RoundRecord:
    """A finished round's controller checked with this run's check settings (its cells reused where unchanged)."""
    done = dataclasses.replace(done, checks=check(ctx, k, Path(done.model)))
    write_record(ctx.folder(k) / "round.json", done)
    return done


def run_round(ctx: Rounds, k: int, model: Path) -> RoundRecord:
    """Round ``k`` from the controller ``model``: acquire at each condition, aggregate, retrain, check, write."""
    section, folder = ctx.stage.acquire, ctx.folder(k)
    beta = section.beta * section.beta_decay ** (k - 1)
    tables = [acquire_at(ctx, k, i, where, model, beta) for i, where in enumerate(ctx.conditions)]
    raw = pa.concat_tables(tables)
    write_table_batches(folder / "acquired.parquet", RAW_SCHEMA, [raw.to_pydict()])
    previous = ctx.folder(k - 1) / "processed" if k > 1 else Path(ctx.stage.paths.processed) / ctx.stage.experiment.name
    train_frames = aggregate(raw, previous, folder / "processed", ctx.stage.experiment.bins)
    retrained, accuracy = retrain(ctx.train_overrides, ctx.stage.model["name"], folder / "processed", folder / "models")
    acquired = [
        AcquiredAt(k, where.label, section.episodes, table.num_rows) for where, table in zip(ctx.conditions, tables)
    ]
    summary = RoundSummary(k, beta, raw.num_rows, train_frames, accuracy, acquired)
    done = RoundRecord(summary, check(ctx, k, retrained), str(retrained), ctx.key)
    write_record(folder / "round.json", done)  # last: its presence marks the round done
    return done


def round_zero(ctx: Rounds, model: Path) -> RoundRecord:
    """The behaviour-cloned controller, checked as every round is (its record: round0/round.json)."""
    metrics = read_checkpoint(model)["metadata"].get("metrics", {})
    frames = read_table(
        Path(ctx.stage.paths.processed) / ctx.stage.experiment.name / "train.parquet", PROCESSED_SCHEMA, ["label"]
    )
    summary = RoundSummary(0, 1.0, 0, frames.num_rows, float(metrics.get("val_accuracy", float("nan"))), [])
    done = RoundRecord(summary, check(ctx, 0, model), str(model), ctx.key)
    write_record(ctx.folder(0) / "round.json", done)
    return done


def log_round(ctx: Rounds, done: RoundRecord) -> None:
    """One MLflow run per round: its sizes, validation accuracy and each check cell's η̂1 with its interval."""
    s, stage = done.summary, ctx.stage
    metrics = {"round": s.round, "beta": s.beta, "frames_added": s.frames_added, "train_frames": s.train_frames}
    metrics["val_accuracy"] = s.val_accuracy
    for c in done.checks:
        metrics.update({f"eta1/{c.cell}": c.eta1, f"eta1_low/{c.cell}": c.low, f"eta1_high/{c.cell}": c.high})
        metrics[f"expert_eta1/{c.cell}"] = c.expert
    name = f"{stage.experiment.name}-{stage.model['name']}-{stage.replicate} round {s.round}"
    with stage_run(stage.paths.root, "acquire", ctx.cfg, run_name=name):
        mlflow.log_metrics(metrics)


def run_acquire(cfg: DictConfig, overrides: Sequence[str]) -> Acquisition:
    """Round 0 (the behaviour-cloned controller), then ``acquire.rounds`` rounds, each reused where it finished
    with the same settings; writes and returns every round's summary and check rows."""
    stage = validate(AcquireStage, cfg)
    section, model = stage.acquire, Path(stage.safety.model_path)
    flagged, training = flagged_cells(sweep_cells(stage), section.target), as_swept(stage, section.training)
    conditions = targeted_conditions(training, flagged)
    further = section.checks if section.rounds else ()  # nothing to compare them with: none driven
    checks = list({w.label: w for w in [*conditions, *further]}.values())
    own = [o for o in overrides if not o.lstrip("+~").startswith("acquire.")]
    ctx = Rounds(
        cfg,
        stage,
        own,
        [o for o in own if o.lstrip("+~").split("=")[0].split(".")[0] in TRAIN_KEYS],
        conditions,
        checks,
        CellRunner.of(stage.executor, stage.progress),
        rounds_key(cfg, model),
    )
    for where in checks:  # every cell composed and checked before any work
        validate(SafetyStage, ctx.safety_config(where, model))
    with ctx.runner:
        history = [round_zero(ctx, model)]
        for k in range(1, section.rounds + 1):
            previous = Path(history[-1].model)
            done = reused_round(ctx, k)
            history.append(rechecked(ctx, k, done) if done else run_round(ctx, k, previous))
    rows = [c for r in history for c in r.checks]
    compared = before_after(rows, training.label, section.margin)
    acquisition = Acquisition(
        stage.model["name"],
        stage.seed,
        stage.experiment.name,
        section.target,
        [w.label for w in conditions[1:]],
        [r.summary for r in history],
        rows,
        compared,
        training.label,
        section.margin,
    )
    shutil.copyfile(history[-1].model, Path(section.out_dir) / CONTROLLER)
    write_record(section.out, acquisition)
    for done in history:
        log_round(ctx, done)
    return acquisition


def describe(a: Acquisition) -> str:
    """The lines a stage prints: each round's frames and η̂1 per check cell against the expert's."""
    lines = []
    for s in a.rounds:
        checks = ", ".join(
            f"{c.cell} {c.eta1:.2f} [{c.low:.2f}, {c.high:.2f}] (expert {c.expert:.2f})"
            for c in a.checks
            if c.round == s.round
        )
        lines.append(f"acquire {a.method} seed{a.replicate} round {s.round}: +{s.frames_added} frames -> {checks}")
    decided = [
        f"{b.cell} {b.verdict} ({b.gain:+.2f}, p={b.p_value:.2g})"
        + (f", {b.non_inferior} within {a.margin:g} (loss >= {b.low:+.2f})" if b.non_inferior else "")
        for b in a.before_after
        if b.round == s.round
    ]
    if decided:
        lines.append(f"  against behaviour cloning (each at {a.before_after[0].level:.2g}): " + ", ".join(decided))
    return "\n".join(lines)
