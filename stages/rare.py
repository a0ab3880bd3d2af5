"""`python stages/rare.py model=vi seed=0`: refute (and with rare.certify=true certify) "η1 ≥ rare.target over the
operating domain" for one offline controller — a Beta law per axis of the envelope's condition space
(`rare.shapes='{noise:[2,5]}'`), importance sampling with a bound valid at any stopping time (docs/rare.md)."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="rare")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.rare_stage import describe, run_rare  # not at the top: workers re-import this script

    print(f"{describe(run_rare(cfg))} -> {cfg.rare.out}")


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.models.schemas import register_schemas as register_models
    from uqdrive.sim.config import register_schemas as register_world

    run_stage(main, register_world, register_models)
