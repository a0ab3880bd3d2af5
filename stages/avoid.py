"""DVC stage `avoid@<method>`: collision avoidance with the warning system, warnings off/on, known/unknown
conditions, calibrated thresholds checked in closed loop (`model=mcd|vi|hmc`)."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="avoid")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.avoid import CONDITIONS, MODES, run_avoid  # not at the top: spawned workers re-import this script
    r = run_avoid(cfg)
    for condition in CONDITIONS:
        for mode in MODES:
            c = r["cells"][condition][mode]
            print(f"avoid {r['method']} {condition:>7} warnings {mode:>10}: eta1 = {c['eta1']:.2f} "
                  f"[{c['eta1_low']:.2f}, {c['eta1_high']:.2f}] n={c['n']}, hand-over {c['handover_rate']:.2f}, "
                  f"full speed {c['full_speed_fraction']:.2f}, warnings 0/1/2 in "
                  f"{c['warning0_runs']}/{c['warning1_runs']}/{c['warning2_runs']} runs")
    k = r["calibration"]
    print(f"calibrated: delta1={k['delta1']:g} delta2={k['delta2']:g} tau={k['tau']:g} "
          f"({'meets' if k['feasible'] else 'cannot meet'} the target {k['target']:g} in replay) "
          f"in {r['seconds']:.0f} s -> {cfg.avoid.out}")


if __name__ == "__main__":
    main()
