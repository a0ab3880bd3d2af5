"""DVC stage `acquire_summary`: metrics/acquisition.json — every controller's acquisition rounds and check rows,
and each method's acquired controllers against its behaviour-cloned ones over the training replicates."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="acquire_summary")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.acquire_summary_stage import describe, run_acquire_summary

    print(describe(run_acquire_summary(cfg), cfg.summary.out))


if __name__ == "__main__":
    run_stage(main)
