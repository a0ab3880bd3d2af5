"""DVC stage `safety`: every cell of the offline-safety sweep (params.yaml: methods × locations × weathers ×
noises) in one process on one pool of workers."""

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="safety_sweep")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.safety_stage import (  # not at the top: workers re-import this script
        describe,
        run_safety_sweep,
    )

    for cell, result in run_safety_sweep(cfg, list(HydraConfig.get().overrides.task)):
        print(f"{describe(cell.safety.cell, result)} -> {cell.safety.out}")


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.models.schemas import register_schemas as register_models
    from uqdrive.sim.config import register_schemas as register_world

    run_stage(main, register_world, register_models)
