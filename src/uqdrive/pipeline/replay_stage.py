"""`uqdrive replay metrics/safety/<cell>.json (--seed S | --first-failure) [--out DIR]`: re-drive one rollout of a
safety cell exactly and write it as a clip (MP4 and GIF) to watch.

The cell's record holds the Hydra overrides that composed it; the command composes them again, plans the cell as the
stage does (`plan_cell`: the same model check and identity) and refuses, in one line, a record whose world is not
the one its overrides compose now, a cell whose identity no longer matches the code, model or config (its rollouts
would not be the ones recorded), and a seed the cell never ran. The re-driven rollout is checked against the record
(outcome, margin; for a failure its termination, steps and path digest) before the clip is written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from uqdrive.records import read_record
from uqdrive.schema import ConfigError

if TYPE_CHECKING:  # imported where used: `uqdrive replay --help` loads no torch
    from uqdrive.safety.cell_records import SafetyCell

DESCRIPTION = (
    "Re-drive one rollout of a safety cell from its record (metrics/safety/<cell>.json) exactly as the cell drove "
    "it, check it against the record, and write a clip (MP4 and GIF) of what the network saw, the path and the "
    "safe set, and eta2, mutual information, warning tier and command over time."
)
BAD_INPUT, DIFFERS = 2, 1


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="uqdrive replay", description=DESCRIPTION)
    p.add_argument("record", help="a safety cell's record, e.g. metrics/safety/mcd-seed0-roundabout-rain-noise0.0.json")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--seed", type=int, help="the rollout seed to re-drive, as the record's failures list it")
    which.add_argument("--first-failure", action="store_true", help="re-drive the record's worst failure")
    p.add_argument("--out", default="replays", help="folder the clip is written to (default: replays)")
    return p.parse_args(argv)


def read_cell(path: str | Path) -> SafetyCell:
    from uqdrive.safety.cell_records import SafetyCell

    """The safety cell at ``path``, or one line saying why it is not one that can be replayed."""
    try:
        cell = read_record(SafetyCell, path, "safety")
    except FileNotFoundError:
        raise ConfigError(
            f"record {path} does not exist; pass a safety cell's record (metrics/safety/<cell>.json)"
        ) from None
    except (ConfigError, json.JSONDecodeError) as err:
        raise ConfigError(f"record {path} is not a safety cell's record ({str(err).split(': ', 1)[-1]})") from None
    if not cell.overrides:
        raise ConfigError(f"record {path} names no overrides to compose its cell from; rerun it: dvc repro safety")
    return cell


def compose_cell(cell: SafetyCell):
    """The cell's config as its overrides compose it now, in this project (paths.root: the working directory, unless
    the cell's overrides name their own)."""
    from hydra import compose, initialize_config_dir

    from uqdrive.models.schemas import register_schemas as register_models
    from uqdrive.resolvers import register_resolvers
    from uqdrive.sim.config import find_conf
    from uqdrive.sim.config import register_schemas as register_world

    register_world()
    register_models()
    register_resolvers()
    overrides = [f"paths.root={json.dumps(str(Path.cwd()))}", "progress=false", *cell.overrides]
    with initialize_config_dir(config_dir=str(find_conf()), version_base="1.3"):
        return compose("safety", overrides=overrides)


def rollout_index(cell: SafetyCell, path: str | Path, seed: int | None) -> int:
    """The index of the rollout to re-drive: the one of ``seed``, or the worst failure's."""
    if seed is None:
        if not cell.failures:
            raise ConfigError(f"record {path}: cell {cell.name} has no failing rollout; choose one with --seed")
        return cell.failures[0].index
    index = seed - cell.base_seed
    if not 0 <= index < len(cell.outcomes):
        last = cell.base_seed + len(cell.outcomes) - 1
        raise ConfigError(f"--seed {seed}: cell {cell.name} never ran it (it ran seeds {cell.base_seed}..{last})")
    return index


def replay(path: str | Path, seed: int | None, out: str | Path) -> tuple[str, bool]:
    """Re-drive the rollout and write its clip; the line to print and whether it matched the record."""
    from uqdrive.pipeline.safety_stage import plan_cell
    from uqdrive.replay.redrive import check_against, redrive
    from uqdrive.replay.video import write_clip
    from uqdrive.safety.failures import placer_for

    cell = read_cell(path)
    index = rollout_index(cell, path, seed)
    plan = plan_cell(compose_cell(cell))
    where = plan.job.where
    if where.location != cell.location:
        raise ConfigError(
            f"record {path} is from world {cell.location!r}; its overrides now compose {where.location!r}: "
            "replay it in the project (and conf/) that wrote it"
        )
    if plan.key != cell.config_hash:
        raise ConfigError(
            f"record {path}: cell {cell.name}'s identity changed since it ran ({cell.config_hash} -> {plan.key}: "
            "code, model or config); rerun it first (dvc repro safety), then replay"
        )
    failure = next((f for f in cell.failures if f.index == index), None)
    watched = redrive(plan.job, index)
    differences = check_against(watched, bool(cell.safe[index]), cell.margins[index], failure)
    r = watched.result
    summary = (
        f"seed {r.seed} (rollout {index} of {cell.name}): {'safe' if r.verdict.safe else 'unsafe'}, "
        f"{r.termination or 'running'} after {r.steps} steps"
        + (f", {failure.cause} at step {failure.step} ({failure.segment})" if failure else "")
    )
    if differences:
        return f"{summary}; DIFFERS from the record: {'; '.join(differences)}", False
    title = f"{cell.method} {cell.location} {cell.weather} noise {cell.noise:g} - seed {r.seed}"
    clip = write_clip(
        watched, title, placer_for(plan.job, index), out, f"{cell.name}-seed{r.seed}", plan.job.control_hz,
        failure=failure,
    )  # fmt: skip
    return f"{summary}; matches the record -> {clip.mp4}, {clip.gif} ({clip.frames} frames)", True


def main(argv: list[str] | None = None) -> int:
    a = parse(argv)
    try:
        line, same = replay(a.record, a.seed, a.out)
    except Exception as err:  # a bad record, seed or config (an override conf/ no longer has): one line, exit 2
        from uqdrive.stage import one_line

        if not isinstance(err, ConfigError) and type(err).__module__.split(".")[0] not in ("hydra", "omegaconf"):
            raise
        print(f"uqdrive replay: {one_line(err) if not isinstance(err, ConfigError) else err}", file=sys.stderr)
        return BAD_INPUT
    print(line)
    return 0 if same else DIFFERS
