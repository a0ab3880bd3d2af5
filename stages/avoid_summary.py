"""DVC stage `avoid_summary`: metrics/avoid.json (every method's cells beside the paper's numbers) and the
paths of all methods coloured by uncertainty."""

import hydra
from omegaconf import DictConfig

from uqdrive.pipeline.avoid_summary_stage import run_avoid_summary
from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="avoid_summary")
@stage_main
def main(cfg: DictConfig) -> None:
    summary = run_avoid_summary(cfg)
    print(f"avoid summary: {len(summary.answers)} answers -> {cfg.summary.out}, figure {cfg.summary.figures_dir}")


if __name__ == "__main__":
    run_stage(main)
