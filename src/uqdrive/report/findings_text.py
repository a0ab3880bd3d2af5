"""The findings as prose: the report's first section and the README's "What the quick run found" are both this
text, rendered from metrics/findings.json (`uqdrive findings` prints it), so no conclusion is written by hand."""

from __future__ import annotations

import argparse
from pathlib import Path

from uqdrive.records import read_record
from uqdrive.report.document import fmt, table

KINDS = {
    ("offline", "method"): "Offline safety, method against method",
    ("offline", "condition"): "Offline safety, each condition against the training condition",
    ("avoid", "method"): "Collision avoidance, method against method (warnings off)",
    ("avoid", "condition"): "Collision avoidance, each unknown condition against the known one (warnings off)",
    ("avoid", "warnings"): "Collision avoidance, warnings on (and calibrated) against off on the same seeds",
}


def _safer(f) -> tuple[str, str]:
    """The finding as "X safer than Y" and the gain in η̂1 with its interval, read in that direction."""
    if f.effect > 0:
        return f"**{f.a}** safer than {f.b}", f"+{f.effect:.2f} [{f.low:+.2f}, {f.high:+.2f}]"
    return f"**{f.b}** safer than {f.a}", f"+{-f.effect:.2f} [{-f.high:+.2f}, {-f.low:+.2f}]"


def findings_markdown(findings) -> str:
    """Supported findings first (each: which way, the effect with its interval, adjusted p, the replicates it rests
    on), grouped by kind; then what was compared and not supported."""
    supported = [f for f in findings.findings if f.supported]
    lines = [
        f"{findings.comparisons} comparisons, each on paired rollouts (the same seeds) of every training replicate, "
        f"decided by the stratified exact McNemar test with Holm's correction over all of them (family-wise error "
        f"≤ {findings.alpha:g}); a difference is supported only if no replicate points the other way. "
        f"**{findings.supported} supported.** The gain is the difference in η̂1 over the replicates' paired runs, "
        "with an interval at the same level (not adjusted)."
    ]
    for (experiment, kind), title in KINDS.items():
        group = [f for f in supported if (f.experiment, f.kind) == (experiment, kind)]
        if not group:
            continue
        rows = [
            [
                *_safer(f),
                fmt(f.adjusted_p, 4) if f.adjusted_p >= 1e-4 else f"{f.adjusted_p:.1e}",
                f"{len(f.agreeing)} of {len(f.replicates)} ({f.pairs} pairs)",
            ]
            for f in sorted(group, key=lambda f: -abs(f.effect))
        ]
        lines.append(
            f"**{title}**\n\n" + table(["finding", "η̂1 gained [interval]", "adjusted p", "replicates agreeing"], rows)
        )
    opposed = [f for f in findings.findings if f.significant and not f.consistent]
    if opposed:
        lines.append(
            "Significant but not supported (some replicate points the other way): "
            + "; ".join(f"{f.name} ({f.effect:+.2f}; opposing replicates {f.opposing})" for f in opposed)
            + "."
        )
    lines.append(
        f"Not supported: {findings.comparisons - findings.supported} comparisons, among them every one whose cells "
        "agree run by run; metrics/findings.json lists each with its counts and p-values."
    )
    return "\n\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from uqdrive.analysis.comparisons import Findings

    parser = argparse.ArgumentParser(prog="uqdrive findings", description=__doc__.splitlines()[0])
    parser.add_argument("path", type=Path, nargs="?", default=Path("metrics/findings.json"))
    args = parser.parse_args(argv)
    print(findings_markdown(read_record(Findings, args.path, "findings")))
    return 0
