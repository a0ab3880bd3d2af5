"""DVC stage `report`: reports/report.md and a self-contained reports/report.html, our numbers beside the paper's."""

import hydra
from omegaconf import DictConfig

from uqdrive.pipeline.report_stage import run_report
from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="report")
@stage_main
def main(cfg: DictConfig) -> None:
    files = run_report(cfg)
    print(f"report: {files.figures} figures -> {files.markdown}, {files.html}")


if __name__ == "__main__":
    run_stage(main)
