"""DVC stages `train_mcd@<experiment>` and `train@<experiment>-<method>`: the posterior for every training seed of
params.yaml (models/<experiment>/<method>/seed<r>.pt), each worker process's share of them stacked into one batch."""

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="train_replicates")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.train_stage import (  # not at the top: workers re-import this script
        describe,
        run_train_replicates,
    )

    for metrics in run_train_replicates(cfg, list(HydraConfig.get().overrides.task)).replicates:
        print(describe(metrics))


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.models.schemas import register_schemas as register_models

    run_stage(main, register_models)
