"""`python stages/acquire.py model=M seed=r acquire.rounds=k`: DAgger rounds for one controller, acquiring where the
previous safety sweep found it unsafe (metrics/acquire/<experiment>/<method>-seed<r>.json)."""

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="acquire")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.acquire_stage import describe, run_acquire  # not at the top: workers re-import this script

    print(describe(run_acquire(cfg, list(HydraConfig.get().overrides.task))))


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.models.schemas import register_schemas as register_models
    from uqdrive.sim.config import register_schemas as register_world

    run_stage(main, register_world, register_models)
