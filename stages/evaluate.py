"""DVC stage `evaluate`: UQ metrics of every method on held-out frames (stage `heldout`) of each weather × noise."""

import hydra
from omegaconf import DictConfig

from uqdrive.pipeline.evaluate_stage import run_evaluate
from uqdrive.stage import run_stage, stage_main


def _fmt(value: float | None) -> str:
    return "undefined" if value is None else f"{value:.3f}"


@hydra.main(version_base="1.3", config_path="../conf", config_name="evaluate")
@stage_main
def main(cfg: DictConfig) -> None:
    table = run_evaluate(cfg)
    for method, by_weather in table.cells.items():
        for weather, by_noise in by_weather.items():
            for noise, m in by_noise.items():
                print(
                    f"evaluate {method} {weather} {noise}: accuracy {m.accuracy:.3f}, NLL {m.nll:.3f}, "
                    f"ECE {m.ece:.3f}, mean MI {m.mean_mutual_information:.3f}, mean η2 {m.mean_eta2:.3f}, "
                    f"AUROC MI {_fmt(m.auroc_mi)}, 1-η2 {_fmt(m.auroc_one_minus_eta2)} ({m.frames} frames)"
                )
    print(f"evaluate -> {cfg.evaluate.out}")


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.sim.config import register_schemas as register_world

    run_stage(main, register_world)
