"""DVC stage `collect`: autopilot episodes of one scenario → data/raw/<scenario>.parquet."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="collect")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.collect import run_collect  # not at the top: spawned workers re-import this script

    result = run_collect(cfg)
    print(
        f"collect: {result['frames']} frames from {result['episodes']} episodes "
        f"(route completed in {result['route_complete_fraction']:.0%}) -> {result['path']}"
    )


if __name__ == "__main__":
    main()
