"""DVC stage `avoid@<method>`: collision avoidance with the warning system, warnings off/on/calibrated, in the
known condition and each unknown one (`model=<method>`, the `avoid` experiment's controllers; `avoid.policy=<file>`:
a policy of yours that gives draws); `--config-name gym_avoid gym_world=<world>` in a Gymnasium world (dvc.yaml's
gym_avoid)."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="avoid")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.avoid.results import Mode
    from uqdrive.pipeline.avoid_stage import run_avoid  # not at the top: spawned workers re-import this script

    r = run_avoid(cfg)
    for condition in r.conditions:
        for mode in Mode:
            c = r.cell(condition, mode)
            e = c.estimate
            print(
                f"avoid {cfg.avoid.name} {condition:>12} warnings {mode:>10}: eta1 = {e.value:.2f} "
                f"[{e.low:.2f}, {e.high:.2f}] n={e.n}, autonomy {c.autonomy:.2f}, "
                f"passed {c.passed_rate:.2f}, "
                f"warnings 0/1/2 in {c.warning0_runs}/{c.warning1_runs}/{c.warning2_runs} runs"
            )
    for mode in Mode:
        u = r.unknown[mode]
        print(
            f"avoid {cfg.avoid.name} unknown mixture warnings {mode:>10}: eta1 = {u.eta1:.2f} "
            f"[{u.eta1_low:.2f}, {u.eta1_high:.2f}], autonomy {u.autonomy:.2f}"
        )
    k = r.calibration.certificate
    print(
        f"calibrated: delta1={k.delta1:g} delta2={k.delta2:g} tau={k.tau:g}, {k.certified} of {k.candidates} "
        f"candidates certified; {k.guarantee} ({r.seconds:.0f} s) -> {cfg.avoid.out}"
    )


if __name__ == "__main__":  # the config groups it composes take their defaults from these schemas
    from uqdrive.models.schemas import register_schemas as register_models
    from uqdrive.policy.warnings import register_schema as register_warning
    from uqdrive.sim.config import register_schemas as register_world

    run_stage(main, register_world, register_warning, register_models)
