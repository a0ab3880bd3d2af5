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
from uqdrive.uq.claims import ClaimResult
from uqdrive.uq.runs_needed import MOST
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


def _interval(low: float | None, high: float | None) -> str:
    return "[no bounded range]" if low is None or high is None else f"[{low:+.2f}, {high:+.2f}]"


def _mean(claim: ClaimResult) -> str:
    return f"{claim.estimate:+.2f} {_interval(claim.low, claim.high)}"


def _sign_line(claim: ClaimResult) -> str:
    """The sign estimand in its own words: how many runs of A beat their paired B, of those that differ."""
    return (
        f"a training run of A beats its paired run of B in {claim.ahead} of {claim.ahead + claim.behind} that differ "
        f"(of {len(claim.replicates)}), at {claim.rollouts} rollouts per run"
    )


def _needed(claim: ClaimResult) -> str:
    """Training runs at which the mean's procedure would decide an undecided claim (power 0.8, simulated)."""
    if claim.verdict is not Verdict.UNDECIDED:
        return "–"
    if claim.runs_needed is None and claim.runs_needed_worst is None:
        return "not computed" if claim.low is not None else "no bounded range"
    study, worst = (f"{n:,}" if n else f"> {MOST:,}" for n in (claim.runs_needed, claim.runs_needed_worst))
    return f"{study} / {worst}"


def _family(claims: list, findings) -> str:
    first, m = claims[0].result, len(claims)
    return (
        f"family: these {m} claims' mean and sign verdicts together, family-wise error ≤ {findings.alpha:g} "
        f"(mean verdicts {fmt(first.level * m, 4)} over {m}, {fmt(first.level, 4)} each; sign verdicts "
        f"{fmt(first.sign_level * m, 4)} over {m}, {fmt(first.sign_level, 4)} each)"
    )


def claims_markdown(findings) -> str:
    """The paper's claims decided for the mean over training runs, one row each; q in a second table; then the
    other method-level families' counts."""
    paper = [c for c in findings.claims if c.family == "paper"]
    if not paper:
        return ""
    mean_rows = [
        [
            c.result.name,
            c.paper or "–",
            f"{sum(c.a_rates) / len(c.a_rates):.2f} vs {sum(c.b_rates) / len(c.b_rates):.2f}",
            _mean(c.result),
            WORDS[c.result.verdict],
            _needed(c.result),
        ]
        for c in paper
    ]
    sign_rows = [[c.result.name, _sign_line(c.result), WORDS[c.result.sign_verdict]] for c in paper]
    decided = sum(c.result.verdict is not Verdict.UNDECIDED for c in paper)
    by_sign = sum(c.result.sign_verdict is not Verdict.UNDECIDED for c in paper)
    first, pairs = paper[0].result, paper[0].pairs
    text = [
        f"**The paper's claims, for the method** ({len(first.replicates)} training runs of each side, {pairs} paired "
        "rollouts each). Estimand: the mean over training runs of the paired difference in η1, A − B (the paper's: "
        "it compares mean rates); its betting interval is valid for every spread of training runs on [−1, 1], "
        f"assuming only that they are i.i.d. Supported: the interval lies above 0; refuted: below; equivalent: "
        f"inside ±{findings.margin:g}. F{_family(paper, findings)[1:]}. **{decided} of {len(paper)} decided "
        "for the mean.** Runs needed: the training runs at which this interval decides the claim with probability "
        "0.8, by simulating it with runs resampled from these / with the worst spread of that mean (every run's "
        "difference at ±1).",
        table(
            [
                "claim (A safer than B), for the mean",
                "paper",
                "ours: mean η̂1, A vs B",
                "mean Δ̂ [interval]",
                "verdict (mean)",
                "runs needed: these runs' spread / worst",
            ],
            mean_rows,
        ),
        "**A second estimand, q** = P(a training run of A scores higher than its paired run of B, among runs that "
        "differ): the exact sign test of q = ½. q is not the mean (A can win most pairs and lose on average) and "
        "not a property of the method alone: it moves with the rollouts a run's score is read from (more rollouts, "
        f"fewer ties and upsets). **{by_sign} of {len(paper)} decided for q.**",
        table(["claim, for q", "runs that differ", "verdict (q)"], sign_rows),
    ]
    for family, title in (("exploratory", "Exploratory"), ("margin", "Margins (lane half-widths, not η1)")):
        members = [c.result for c in findings.claims if c.family == family]
        if members:
            text.append(_family_line(title, members, findings))
    return "\n\n".join(text)


def _family_line(title: str, members: list[ClaimResult], findings) -> str:
    """One family's counts, for the mean and for q, each decided claim named under its own estimand."""
    parts = []
    for what, read in (("for the mean", lambda c: c.verdict), ("for q", lambda c: c.sign_verdict)):
        if what == "for the mean" and all(c.low is None for c in members):
            continue
        counts = {v: sum(read(c) is v for c in members) for v in Verdict}
        listed = "; ".join(
            f"{c.name}: {WORDS[read(c)]} ({_mean(c) if what == 'for the mean' else _sign_line(c)})"
            for c in members
            if read(c) is not Verdict.UNDECIDED
        )
        equivalent = f", equivalent {counts[Verdict.EQUIVALENT]}" if what == "for the mean" else ""
        parts.append(
            f"{what}: supported {counts[Verdict.SUPPORTED]}, refuted {counts[Verdict.REFUTED]}{equivalent}"
            + (f" — {listed}" if listed else "")
        )
    m = len(members)
    return (
        f"**{title}, for the method** ({m} claims; family: these {m} claims' verdicts, family-wise error ≤ "
        f"{findings.alpha:g}): " + "; ".join(parts) + "."
    )


def span(low: float, high: float, digits: int = 2) -> str:
    """A range of values as printed: one number where both ends print the same (never "1.00–1.00")."""
    a, b = fmt(low, digits), fmt(high, digits)
    return a if a == b else f"{a}–{b}"


def _safer(record) -> tuple[str, str, str]:
    """The finding read as "X safer than Y": the safer cell's label, the other's, and the average gain in η̂1 with
    its interval in that direction."""
    f = record.finding
    if f.low > 0 or (f.high >= 0 and f.effect > 0):
        return record.a, record.b, f"+{f.effect:.2f} {_interval(f.low, f.high)}"
    return record.b, record.a, f"+{-f.effect:.2f} {_interval(-f.high, -f.low)}"


def _without_method(label: str) -> str:
    return label.split(" ", 1)[1] if " " in label else label


def _group_row(members: list) -> list[str]:
    """One row for findings that say one thing of many cells: the safer and the other conditions (without the
    method), the methods it holds for, how many findings, the range of their gains and the largest p."""
    largest = max(f.finding.p_value for f in members)
    p = fmt(largest, 4) if largest >= 1e-4 else f"{largest:.1e}"
    if len(members) == 1:
        safer, other, gain = _safer(members[0])
        return [f"**{safer}** safer than {other}", gain, p]
    read = [_safer(f) for f in members]
    safer = ", ".join(dict.fromkeys(_without_method(s) for s, _, _ in read))
    other = ", ".join(dict.fromkeys(_without_method(o) for _, o, _ in read))
    methods = ", ".join(dict.fromkeys(f.a.split()[0] for f in members))
    gains = [abs(f.finding.effect) for f in members]
    what = f"**{safer}** safer than {other}, for {methods} ({len(members)} findings)"
    return [what, f"+{span(min(gains), max(gains))} (each excludes 0)", p]


def controller_markdown(findings) -> str:
    """Supported controller-level findings, grouped by kind; within a kind, those that say one thing of many cells
    (e.g. every method is less safe at one location in every weather) are one row."""
    supported = [f for f in findings.findings if f.finding.supported]
    first = findings.findings[0].finding if findings.findings else None
    design = f"{len(first.replicates)} controllers, {first.runs} runs each" if first else "no comparisons"
    lines = [
        f"**For these trained controllers** ({design}): {findings.comparisons} comparisons, each on paired rollouts "
        "(the same seeds). A finding's interval is for **the average gain over these controllers**: the betting "
        "interval for the mean of their paired differences, valid however unlike the controllers are, Bonferroni "
        f"over all comparisons (family-wise error ≤ {findings.alpha:g}); supported exactly when it excludes 0. "
        f"**{findings.supported} supported.**"
    ]
    for (experiment, kind), title in KINDS.items():
        group = [f for f in supported if (f.experiment, f.kind) == (experiment, kind)]
        rows = []
        key = lambda f: (f.topic, f.finding.effect > 0)  # noqa: E731  (one fact of many cells: one row)
        for _, members in itertools.groupby(sorted(group, key=key), key=key):
            rows.append(_group_row(sorted(members, key=lambda f: -abs(f.finding.effect))))
        if rows:
            header = ["finding", "average η̂1 gained [interval]", "p (largest)"]
            lines.append(f"**{title}**\n\n" + table(header, rows))
    return "\n\n".join(lines)


def findings_markdown(findings) -> str:
    return "\n\n".join(part for part in (claims_markdown(findings), controller_markdown(findings)) if part)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="uqdrive findings", description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument(
        "path",
        type=Path,
        nargs="?",
        default=Path("metrics/findings.json"),
        help="the findings record (default: metrics/findings.json)",
    )
    args = parser.parse_args(argv)
    from uqdrive.analysis.comparisons import Findings  # after the arguments: it loads torch

    print(findings_markdown(read_record(Findings, args.path, "findings")))
    return 0
