"""The findings as prose: the report's first section and the README's results are both this text, rendered from
metrics/findings.json (`uqdrive findings` prints it), so no conclusion is written by hand.

It leads with the method-level answers (what a posterior family does over its training runs: the paper's claims,
claim by claim), then what the exploratory and margin families decided, then the findings for these trained
controllers, grouped so that one fact seen in many cells is one line.
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

from uqdrive.records import read_record
from uqdrive.report.document import fmt, table
from uqdrive.uq.verdict import Verdict

KINDS = {
    ("offline", "method"): "Offline safety, method against method",
    ("offline", "condition"): "Offline safety, each condition against the training condition",
    ("avoid", "method"): "Collision avoidance, method against method (warnings off)",
    ("avoid", "condition"): "Collision avoidance, each unknown condition against the known one (warnings off)",
    ("avoid", "warnings"): "Collision avoidance, warnings on (and calibrated) against off on the same seeds",
}
WORDS = {
    Verdict.SUPPORTED: "**supported**",
    Verdict.REFUTED: "**refuted** (the other way)",
    Verdict.EQUIVALENT: "**equivalent** within ±δ",
    Verdict.UNDECIDED: "undecided",
}


def _interval(low: float, high: float) -> str:
    return f"[{low:+.2f}, {high:+.2f}]"


def _estimate(claim) -> str:
    """Δ̂ and its interval; where the verdict rests on the equivalence interval (wider: its variance is floored at the
    margin's) and that differs, that one too, so "undecided" is read against the interval that decided it."""
    text = f"{claim.estimate:+.2f} {_interval(claim.low, claim.high)}"
    equivalence = (claim.equivalence_low, claim.equivalence_high)
    if claim.verdict in (Verdict.EQUIVALENT, Verdict.UNDECIDED) and equivalence != (claim.low, claim.high):
        text += f", ±δ test {_interval(*equivalence)}"
    return text


def _detectable(claim) -> str:
    """The smallest difference this design detects at 80 % power, and the replicates that would detect δ (none to
    say where no replicate's pair differs: no spread to plan from)."""
    if claim.sd == 0:
        return "no spread to plan from"
    detects = "none below 1" if claim.detectable > 1 else f"{claim.detectable:.2f}"
    needed = f", δ = {claim.margin:g} needs {claim.needed} replicates" if claim.needed else ""
    return detects + needed


def claims_markdown(findings) -> str:
    """The paper's claims decided for the method, one row each, then the other method-level families' counts."""
    paper = [c for c in findings.claims if c.family == "paper"]
    if not paper:
        return ""
    rows = [
        [
            c.name,
            c.paper or "–",
            f"{sum(c.a_rates) / len(c.a_rates):.2f} vs {sum(c.b_rates) / len(c.b_rates):.2f}",
            _estimate(c),
            WORDS[c.verdict] + (f" ({c.reason})" if c.verdict is Verdict.UNDECIDED else ""),
            _detectable(c),
        ]
        for c in paper
    ]
    decided = sum(c.verdict is not Verdict.UNDECIDED for c in paper)
    first = paper[0]
    text = [
        f"**The paper's claims, for the method** (each posterior family over its training runs: "
        f"{len(first.replicates)} replicates, {first.pairs} paired runs each). Each claim is decided by Student's t "
        f"across replicates of the paired difference, at {fmt(first.level, 4)} each (Bonferroni over the "
        f"{len(paper)} claims: family-wise error ≤ {findings.alpha:g}), assuming {first.assumption}. Verdicts: "
        f"supported, refuted, equivalent within ±{findings.margin:g}, or undecided. **{decided} of {len(paper)} "
        "decided.**",
        table(["claim (A safer than B)", "paper", "ours: A vs B", "Δ̂ [interval]", "verdict", "detects"], rows),
    ]
    for family, title in (("exploratory", "Exploratory"), ("margin", "Margins (a separate estimand, not η1)")):
        members = [c for c in findings.claims if c.family == family]
        if members:
            counts = {v: sum(c.verdict is v for c in members) for v in Verdict}
            listed = "; ".join(
                f"{c.name}: {WORDS[c.verdict]} {c.estimate:+.2f} {_interval(c.low, c.high)}"
                for c in members
                if c.verdict is not Verdict.UNDECIDED
            )
            text.append(
                f"**{title}, for the method**: {len(members)} claims, supported {counts[Verdict.SUPPORTED]}, "
                f"refuted {counts[Verdict.REFUTED]}, equivalent {counts[Verdict.EQUIVALENT]}"
                + (f" — {listed}." if listed else ".")
            )
    return "\n\n".join(text)


def _safer(f) -> tuple[str, str]:
    """The finding as "X safer than Y" and the gain in η̂1 with its interval, read in that direction."""
    if f.effect > 0:
        return f"**{f.a}** safer than {f.b}", f"+{f.effect:.2f} {_interval(f.low, f.high)}"
    return f"**{f.b}** safer than {f.a}", f"+{-f.effect:.2f} {_interval(-f.high, -f.low)}"


def _method(label: str) -> str:
    return label.split()[0]


def controller_markdown(findings) -> str:
    """Supported controller-level findings, grouped by kind; within a kind, those that say one thing of many cells
    (e.g. every method is less safe at one location in every weather) are one row."""
    supported = [f for f in findings.findings if f.supported]
    lines = [
        f"**For these trained controllers**: {findings.comparisons} comparisons, each on paired rollouts (the same "
        f"seeds) of every training replicate, decided by the stratified exact McNemar test with Holm's correction "
        f"over all of them (family-wise error ≤ {findings.alpha:g}); supported only if every replicate shows a "
        f"difference of the same sign. **{findings.supported} supported.** The interval is the inversion of the "
        "finding's own test at the level Holm grants it, on the difference scale at the observed discordance."
    ]
    for (experiment, kind), title in KINDS.items():
        group = [f for f in supported if (f.experiment, f.kind) == (experiment, kind)]
        rows = []
        key = lambda f: (f.topic, f.effect > 0)  # noqa: E731  (one fact of many cells: one row)
        for _, members in itertools.groupby(sorted(group, key=key), key=key):
            members = sorted(members, key=lambda f: -abs(f.effect))
            what, gain = _safer(members[0])
            if len(members) > 1:
                controllers = sorted({_method(f.a) for f in members})
                what = f"{what} (and alike for {len(members) - 1} more: {', '.join(controllers)})"
                gains = [abs(f.effect) for f in members]
                gain = f"{min(gains):.2f}–{max(gains):.2f}"
            adjusted = max(f.adjusted_p for f in members)
            rows.append([what, gain, fmt(adjusted, 4) if adjusted >= 1e-4 else f"{adjusted:.1e}"])
        if rows:
            lines.append(f"**{title}**\n\n" + table(["finding", "η̂1 gained [interval]", "adjusted p (largest)"], rows))
    opposed = [f for f in findings.findings if f.significant and not f.supported]
    if opposed:
        lines.append(
            "Significant but not supported: "
            + "; ".join(f"{f.name} ({f.effect:+.2f}; {f.reason})" for f in opposed)
            + "."
        )
    return "\n\n".join(lines)


def findings_markdown(findings) -> str:
    return "\n\n".join(part for part in (claims_markdown(findings), controller_markdown(findings)) if part)


def main(argv: list[str] | None = None) -> int:
    from uqdrive.analysis.comparisons import Findings

    parser = argparse.ArgumentParser(prog="uqdrive findings", description=__doc__.splitlines()[0])
    parser.add_argument("path", type=Path, nargs="?", default=Path("metrics/findings.json"))
    args = parser.parse_args(argv)
    print(findings_markdown(read_record(Findings, args.path, "findings")))
    return 0
