"""`python stages/train.py experiment=E model=M seed=r`: fit the posterior conf/model/<M>.yaml names for one training
seed (replicate); all but MCD need the replicate's models/<E>/mcd/seed<r>.pt (the DVC stages: train_replicates.py)."""

import hydra
from omegaconf import DictConfig

from uqdrive.pipeline.train_stage import describe, run_train
from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="train")
@stage_main
def main(cfg: DictConfig) -> None:
    print(f"{describe(run_train(cfg))} -> {cfg.paths.models}/{cfg.replicate}.pt")


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.models.schemas import register_schemas as register_models

    run_stage(main, register_models)
