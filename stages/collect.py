"""DVC stage `collect`: autopilot episodes of one scenario → data/raw/<scenario>.parquet."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="collect")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.collect_stage import describe, run_collect  # not at the top: workers re-import this script

    print(describe(run_collect(cfg), cfg.collect.out))


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.sim.config import register_schemas as register_world

    run_stage(main, register_world)
