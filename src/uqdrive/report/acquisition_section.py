"""The report's section on data acquisition (stages `acquire`, `acquire_summary`): where each controller's sweep
flagged it and how many frames each round acquired there, then behaviour cloning against the last round at every
check cell — per trained controller (exact paired tests) and per method over its replicates — with the expert's η̂1
on the same seeds as the reference line. Reads only metrics/acquisition.json."""

from __future__ import annotations

from uqdrive.acquire.acquisition import Acquisition
from uqdrive.analysis.acquisition_summary import AcquisitionSummary
from uqdrive.report.document import Report, fmt, table


def _interval(value: float, low: float, high: float) -> str:
    return f"{fmt(value)} [{fmt(low)}, {fmt(high)}]"


def _rounds_table(controllers: list[Acquisition]) -> str:
    rows = [
        [
            f"{a.method} seed{a.replicate}",
            str(s.round),
            fmt(s.beta),
            ", ".join(f"{x.condition}: {x.frames}" for x in s.acquired),
            str(s.train_frames),
            fmt(s.val_accuracy, 3),
        ]
        for a in controllers
        for s in a.rounds
        if s.round > 0
    ]
    headers = ["controller", "round", "β", "frames acquired, by condition", "training frames", "val. accuracy"]
    return table(headers, rows)


def _controllers_table(controllers: list[Acquisition]) -> str:
    rows = []
    for a in controllers:
        last = max(s.round for s in a.rounds)
        by = {(c.round, c.cell): c for c in a.checks}
        compared = {b.cell: b for b in a.before_after if b.round == last}
        for before in (c for c in a.checks if c.round == 0):
            cell = before.cell
            after, b = by[last, cell], compared.get(cell)
            verdict = "—" if b is None else f"{b.verdict} ({b.gain:+.2f}, p {b.p_value:.2g})"
            held = f"; {b.non_inferior} within {a.margin:g}" if b is not None and b.non_inferior else ""
            rows.append(
                [
                    f"{a.method} seed{a.replicate}",
                    cell + (" (training)" if cell == a.training else ""),
                    _interval(before.eta1, before.low, before.high),
                    _interval(after.eta1, after.low, after.high) if last else "—",
                    _interval(before.expert, before.expert_low, before.expert_high),
                    verdict + held,
                ]
            )
    headers = ["controller", "check cell", "behaviour cloning", "last round", "expert", "paired test"]
    return table(headers, rows)


def _methods_table(summary: AcquisitionSummary) -> str:
    rows = [
        [
            g.method,
            g.cell,
            str(g.round),
            fmt(g.behaviour_cloned),
            fmt(g.acquired),
            fmt(g.expert),
            f"{g.claim.verdict}" + (f" ({g.claim.reason})" if g.claim.reason else ""),
            g.non_inferior or "—",
        ]
        for g in summary.methods
    ]
    headers = ["method", "check cell", "round", "behaviour cloning", "acquired", "expert", "acquired safer?"]
    return table([*headers, f"training cell within {summary.margin:g}"], rows)


def acquisition_section(report: Report, summary: AcquisitionSummary) -> None:
    """Rounds and frames, then the controller-level and method-level comparison with behaviour cloning."""
    controllers = summary.controllers
    rounds = max(s.round for a in controllers for s in a.rounds)
    report.add(f"""
## Data acquisition where the sweep found the controllers unsafe

Each `{summary.experiment}` controller's acquisition (DAgger): a round drives it at the training condition and at
each condition its sweep flagged (upper end of η1's interval below the target), the expert driving a step with
probability β, labels every frame with the expert's command in that state, retrains on all frames so far and checks
η̂1 at every check cell on the sweep's seeds, beside the expert on the same seeds.""")
    if rounds == 0:
        report.add(
            "No round was run (`acquire_rounds: 0`): the behaviour-cloned controllers at their check cells, beside "
            "the expert (`dvc exp run -S acquire_rounds=2` acquires).\n\n" + _controllers_table(controllers)
        )
        return
    report.add(_rounds_table(controllers))
    report.add(
        "**These trained controllers.** The last round against behaviour cloning, paired by seed: exact McNemar "
        "test, Bonferroni over every round × cell of the controller and its training-cell non-inferiority checks "
        "(the gain's interval covers for any joint law of the pairs).\n\n" + _controllers_table(controllers)
    )
    report.add(
        f"**The method** (over its training runs; assumption: i.i.d. training runs): per check cell, the claim "
        f'"acquired safer than behaviour-cloned" by the sign test and the betting interval of the mean gain, one '
        f"family at α = {summary.alpha:g}; at the training cell, non-inferior when the mean loss is bounded below "
        f"{summary.margin:g}.\n\n" + _methods_table(summary)
    )
