"""DVC stage `findings`: every comparison the report states, decided over the training replicates — for these
trained controllers (a majority of them, exact) and for the method (sign test and betting interval, valid whatever
the training runs do), Bonferroni within each family (metrics/findings.json)."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="findings")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.findings_stage import run_findings

    findings = run_findings(cfg)
    for f in (record.finding for record in findings.findings):
        if f.supported:
            interval = f"[{f.low:+.2f}, {f.high:+.2f}]"
            print(f"supported: {f.name}: {f.effect:+.2f} {interval}, p {f.p_value:.2g} at level {f.level:.2g}")
    print(
        f"findings: {findings.supported} of {findings.comparisons} comparisons supported at family-wise "
        f"alpha={findings.alpha:g} -> {cfg.findings.out}"
    )


if __name__ == "__main__":
    run_stage(main)
