"""The report's first screen: the short answer, generated from the records (what is safe, where not, which
findings hold and at which level)."""

from __future__ import annotations

from uqdrive.analysis.comparisons import Findings
from uqdrive.analysis.method_answers import SafetySummary
from uqdrive.report.findings_text import KINDS, span
from uqdrive.report.headline import Headline, eta1_text
from uqdrive.uq.verdict import Verdict

SAFE, UNSAFE = 0.9, 0.5  # the short answer's words: η̂1 ≥ SAFE for every method is "safe", < UNSAFE "unsafe"


def _by_method(values: dict) -> str:
    return ", ".join(f"{m} {eta1_text(v)}" for m, v in values.items())


def _conditions(safety: SafetySummary, methods: list[str], keep) -> tuple[list[str], int]:
    """Conditions where every method's η̂1 passes ``keep``, with the range of the methods' η̂1 there; a location
    where every condition passes is one item."""
    values: dict[str, list[float]] = {}
    for a in safety.answers:
        if a.method in methods:
            values.setdefault(a.condition, []).append(a.value)
    passing = [c for c, v in values.items() if all(keep(x) for x in v)]
    found, done = [], set()
    for condition in passing:
        location = condition.split("-", 1)[0]
        everywhere = [c for c in values if c.split("-", 1)[0] == location]
        if len(everywhere) > 1 and set(everywhere) <= set(passing):
            if location not in done:
                every = [x for c in everywhere for x in values[c]]
                found.append(f"{location}, all {len(everywhere)} of its conditions ({span(min(every), max(every))})")
                done.add(location)
        else:
            found.append(f"{condition} ({span(min(values[condition]), max(values[condition]))})")
    return found, len(passing)


def _where(safety: SafetySummary, methods: list[str]) -> list[str]:
    (safe, n_safe), (unsafe, n_unsafe) = (_conditions(safety, methods, keep) for keep in (_safe, _unsafe))
    total = len({a.condition for a in safety.answers})
    safe_text, unsafe_text = "; ".join(safe) or "none", "; ".join(unsafe) or "none"
    return [
        f"- **Safe by the point estimates** (every method's η̂1 ≥ {SAFE:g}; the intervals are in the chart) in "
        f"{n_safe} of the sweep's {total} conditions: {safe_text}.",
        f"- **Not safe by the point estimates** (every method's η̂1 < {UNSAFE:g}) in {n_unsafe}: {unsafe_text}.",
    ]


def _safe(value: float) -> bool:
    return value >= SAFE


def _unsafe(value: float) -> bool:
    return value < UNSAFE


def _held(findings: Findings) -> list[str]:
    paper = [c.result for c in findings.claims if c.family == "paper"]
    decided = [c for c in paper if c.verdict is not Verdict.UNDECIDED]
    kinds = {}
    for f in findings.findings:
        if f.finding.supported:
            kinds[f.experiment, f.kind] = kinds.get((f.experiment, f.kind), 0) + 1
    listed = "; ".join(f"{KINDS.get(k, ' '.join(k)).lower()}: {n}" for k, n in kinds.items())
    lines = (
        [
            f"- **The paper's claims, for the method** (over {len(paper[0].replicates)} training runs each): "
            f"{len(decided)} of {len(paper)} decided, family-wise error ≤ {findings.alpha:g}"
            + (": " + "; ".join(f"{c.name} {c.verdict}" for c in decided) if decided else "")
            + "."
        ]
        if paper
        else []
    )
    lines.append(
        f"- **For these trained controllers**: {findings.supported} of {findings.comparisons} comparisons supported, "
        f"family-wise error ≤ {findings.alpha:g}" + (f" ({listed})." if listed else ".")
    )
    return lines


def answer_markdown(
    headline: Headline, safety: SafetySummary, findings: Findings, methods: list[str], training: str
) -> str:
    """The short answer: η̂1 where trained and over the sweep, where safe and where not, the warnings, the findings;
    every number from the records, each η̂1 with its method interval."""
    h, by = headline, _by_method
    lines = [
        f"Each η̂1 is the mean over {headline.n_replicates} training replicates with an interval for the method's η1 "
        "(η1: the probability that a rollout stays in its safe set); with few replicates that interval is wide. "
        '"these:" is the interval for the mean η1 of these trained controllers, what their rollouts do support.',
        "",
        f"- **At the training condition** ({training}): {by(h.eta1_training_condition)}.",
        f"- **Over the training location's weathers × noises**: {by(h.eta1_training_location)}; "
        f"**over every cell of the sweep**: {by(h.eta1_all_sweep_cells)}.",
        *_where(safety, methods),
        f"- **Collision avoidance, unknown conditions**: warnings off {by(h.avoid_unknown_off)}; "
        f"on {by(h.avoid_unknown_on)}; calibrated {by(h.avoid_unknown_calibrated)}.",
        *_held(findings),
    ]
    return "\n".join(lines)
