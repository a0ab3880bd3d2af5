"""`python stages/certify.py certify.policy=my_policy.yaml`: a user's policy certified "eta1 >= certify.eta" in a
world, or refused; exits 0 only when certified (1 refuted, 3 undecided, 2 a bad config or policy file)."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="certify")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.certify_stage import (  # not at the top: spawned workers re-import this script
        EXIT,
        describe,
        run_certify,
    )

    record = run_certify(cfg)
    print(f"{describe(record)} -> {cfg.certify.out}")
    if EXIT[record.verdict]:
        raise SystemExit(EXIT[record.verdict])


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.sim.config import register_schemas as register_world

    run_stage(main, register_world)
