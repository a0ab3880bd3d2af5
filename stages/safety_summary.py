"""DVC stage `safety_summary`: metrics/safety.json (each method's answer over its replicates per condition) and
the offline-safety figures."""

import hydra
from omegaconf import DictConfig

from uqdrive.pipeline.safety_summary_stage import run_safety_summary
from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="safety_summary")
@stage_main
def main(cfg: DictConfig) -> None:
    summary = run_safety_summary(cfg)
    print(f"safety summary: {len(summary.answers)} answers -> {cfg.summary.out}, figures {cfg.summary.figures_dir}")


if __name__ == "__main__":
    run_stage(main)
