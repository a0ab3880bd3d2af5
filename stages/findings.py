"""DVC stage `findings`: every comparison the report states, decided by exact paired tests over the training
replicates, Holm-corrected over the whole family (metrics/findings.json)."""

import hydra
from omegaconf import DictConfig

from uqdrive.stage import run_stage, stage_main


@hydra.main(version_base="1.3", config_path="../conf", config_name="findings")
@stage_main
def main(cfg: DictConfig) -> None:
    from uqdrive.pipeline.findings_stage import run_findings

    findings = run_findings(cfg)
    for f in findings.findings:
        if f.supported:
            print(f"supported: {f.name}: {f.effect:+.2f} [{f.low:+.2f}, {f.high:+.2f}], adjusted p {f.adjusted_p:.2g}")
    print(
        f"findings: {findings.supported} of {findings.comparisons} comparisons supported at family-wise "
        f"alpha={findings.alpha:g} -> {cfg.findings.out}"
    )


if __name__ == "__main__":
    run_stage(main)
