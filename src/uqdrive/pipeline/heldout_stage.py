"""The `heldout` stage: held-out autopilot frames in every weather × noise of the sweep, on episode seeds the
training collection never uses (conf/heldout.yaml), each condition as the single-condition collect command
composes it, all in one process on one pool of workers."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from functools import partial

from omegaconf import DictConfig

from uqdrive.parallel import ProcessPool
from uqdrive.pipeline.collect_stage import Collection, CollectStage, run_collect
from uqdrive.schema import validate
from uqdrive.sim.collect_plan import HeldoutStage
from uqdrive.stage import grid, run_cells
from uqdrive.tracking import stage_parent_run


def run_heldout(cfg: DictConfig, overrides: Sequence[str]) -> Iterator[tuple[DictConfig, Collection]]:
    """Held-out frames in every condition of ``cfg.sweep`` (weathers × noises); yields each condition's config and
    collection as it finishes (`uqdrive.stage.run_cells`)."""
    stage = validate(HeldoutStage, cfg)
    cells = grid(weather=stage.sweep.weathers, noise=stage.sweep.noises)
    pool = ProcessPool(stage.collect.workers)
    parent = partial(stage_parent_run, stage.paths.root, "collect", cfg, overrides, name=f"heldout: {len(cells)} cells")
    yield from run_cells("heldout", overrides, cells, CollectStage, run_collect, pool, stage.progress, parent)
