"""DVC stage `preprocess`: grayscale 64x48 frames, steering classes, train/val split by episode."""

import hydra
from omegaconf import DictConfig

from uqdrive.pipeline.preprocess_stage import run_preprocess
from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="preprocess")
@stage_main
def main(cfg: DictConfig) -> None:
    metrics = run_preprocess(cfg)
    print(
        f"preprocess: {metrics.train_frames} train / {metrics.val_frames} val frames, "
        f"{metrics.num_classes} classes -> {cfg.paths.processed}"
    )


if __name__ == "__main__":
    run_stage(main)
