"""`python stages/envelope.py model=vi seed=0`: the certified operating envelope of one offline controller over
continuous condition axes (default: sensor noise × a clear-to-rain weather blend at the training roundabout); the DVC
stage `envelope@<method>`. Other axes, e.g.
`envelope.axes='[{key:scenario.ring_radius,range:[10,24]},{key:noise,range:[0,0.2]}]'`."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="envelope")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.envelope_stage import describe, run_envelope  # not at the top: workers re-import this script

    print(f"{describe(run_envelope(cfg))} -> {cfg.envelope.out}")


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.models.schemas import register_schemas as register_models
    from uqdrive.sim.config import register_schemas as register_world

    run_stage(main, register_world, register_models)
