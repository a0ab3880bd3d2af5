"""DVC stage `train@<method>`: fit the posterior conf/model/<method>.yaml names
(`model=mcd|vi|hmc|ensemble|laplace|…`); all but MCD need models/mcd.pt."""

import hydra
from omegaconf import DictConfig

from uqdrive.pipeline.train import run_train
from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="train")
@stage_main
def main(cfg: DictConfig) -> None:
    m = run_train(cfg)
    print(
        f"train {m['method']}: val accuracy {m['val_accuracy']:.3f} (majority baseline "
        f"{m['majority_baseline_accuracy']:.3f}), NLL {m['val_nll']:.3f}, ECE {m['val_ece']:.3f} "
        f"in {m['train_seconds']:.0f} s -> {cfg.paths.models}/{m['method']}.pt"
    )


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.models.schemas import register_schemas as register_models

    run_stage(main, register_models)
