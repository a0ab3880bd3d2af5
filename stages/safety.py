"""`python stages/safety.py model=vi weather=rain noise=0.1`: η1 of one controller in one cell of the sweep
(`-m` sweeps cells; the DVC stage `safety` runs params.yaml's whole sweep: stages/safety_sweep.py)."""

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="safety")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.safety_stage import (  # not at the top: spawned workers re-import this script
        describe,
        run_safety,
    )

    result = run_safety(cfg, overrides=list(HydraConfig.get().overrides.task))  # kept in the record: replay
    print(f"{describe(cfg.safety.cell, result)} -> {cfg.safety.out}")


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.models.schemas import register_schemas as register_models
    from uqdrive.sim.config import register_schemas as register_world

    run_stage(main, register_world, register_models)
