"""DVC stage `heldout`: the collect stage's autopilot at the roundabout in every weather × noise of params.yaml,
on episode seeds training never uses, in one process on one pool of workers."""

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="heldout_sweep")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.collect_stage import describe  # not at the top: workers re-import this script
    from uqdrive.pipeline.heldout_stage import run_heldout

    for condition, collection in run_heldout(cfg, list(HydraConfig.get().overrides.task)):
        print(describe(collection, condition.collect.out))


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.sim.config import register_schemas as register_world

    run_stage(main, register_world)
