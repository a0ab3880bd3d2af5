"""DVC stage `safety@<cell>`: η1 of one controller (`model=<method>`) in one weather and noise level."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="safety")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.safety import run_safety  # not at the top: spawned workers re-import this script

    r = run_safety(cfg)
    print(
        f"safety {cfg.safety.cell}: eta1 = {r['eta1']:.3f} in [{r['eta1_low']:.3f}, {r['eta1_high']:.3f}] "
        f"from {r['n']} rollouts ({r['scheme']}, theta={r['theta']:g}, gamma={r['gamma']:g})"
        f"{' (reused: config unchanged)' if r['reused'] else ''} -> {cfg.safety.out}"
    )


if __name__ == "__main__":
    main()
