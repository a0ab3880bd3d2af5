"""The headline numbers: metrics/summary.json (DVC's one metrics file, so `dvc exp show`'s first columns) and the
table the report and the README print from it (`uqdrive headline`), so the README cannot drift from the run.

Each η̂1 is named for what it averages — the training condition, the training location's weather × noise cells,
every cell of the sweep — and carries its interval for the method: an average that silently took in the 20 m
ring, where every controller fails, once read as the roundabout's safety.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml
from pydantic import TypeAdapter, ValidationError

from uqdrive.analysis.comparisons import Findings
from uqdrive.analysis.method_answers import UNKNOWN, MethodAnswer, controllers_bounds, pooled_answer
from uqdrive.avoid.results import Mode
from uqdrive.records import record
from uqdrive.report.document import fmt, table
from uqdrive.resolvers import condition_label
from uqdrive.schema import ConfigError, describe


@record
class Eta1:
    """A method's η̂1 (the mean over its replicates), the interval for its η1 over training runs (``low``, ``high``)
    and the interval for the mean η1 of these trained controllers (``ctl_low``, ``ctl_high``:
    `method_answers.controllers_bounds`; None in a summary written before it was recorded)."""

    value: float
    low: float
    high: float
    ctl_low: float | None = None
    ctl_high: float | None = None


@record
class Headline:
    """metrics/summary.json in `dvc exp show`'s order: per driven method, η̂1 at the training condition (training
    location and weather, noise 0), over the training location's weather × noise cells, over every cell of the
    offline sweep (every location), and in collision avoidance's unknown conditions (warnings off, on,
    calibrated), each with its interval; then the loosest (θ, γ) of the closed-loop cells, how many training
    replicates each number averages, each experiment's validation accuracy and how many findings hold."""

    eta1_training_condition: dict[str, Eta1 | None]  # None: the sweep does not hold the training condition
    eta1_training_location: dict[str, Eta1]
    eta1_all_sweep_cells: dict[str, Eta1]
    avoid_unknown_off: dict[str, Eta1]
    avoid_unknown_on: dict[str, Eta1]
    avoid_unknown_calibrated: dict[str, Eta1]
    theta: float
    gamma: float
    n_replicates: int
    val_accuracy: dict[str, dict[str, float]]  # experiment → method
    findings_supported: int


# metrics/summary.json's short names (`dvc exp show` gives each a column): a Headline field → its key's prefix
SHORT_NAMES = {
    "eta1_training_condition": "eta1.train",
    "eta1_training_location": "eta1.loc",
    "eta1_all_sweep_cells": "eta1.sweep",
    "avoid_unknown_off": "avoid.off",
    "avoid_unknown_on": "avoid.on",
    "avoid_unknown_calibrated": "avoid.calib",
    "findings_supported": "findings",
    "theta": "theta",
    "gamma": "gamma",
    "n_replicates": "replicates",
    "val_accuracy": "val_acc",
}
_HEADLINE_FIRST = ("eta1_training_condition", "findings_supported")  # the answer, then how many findings hold


def summary_keys(headline: Headline) -> dict[str, float | int | None]:
    """The headline as metrics/summary.json holds it: one flat key per number, short enough that `dvc exp show`
    shows the answer in 200 columns: ``eta1.train.mcd`` (η̂1) with ``eta1.train.mcd.low`` and ``.high`` (its
    interval for the method), ``.ctl_low`` and ``.ctl_high`` (for these trained controllers; only the value, null,
    where the sweep lacks the condition), ``findings``, ``val_acc.<experiment>.<method>``…"""
    out: dict[str, float | int | None] = {}
    order = [*_HEADLINE_FIRST, *(f for f in SHORT_NAMES if f not in _HEADLINE_FIRST)]
    for field in order:
        value, prefix = getattr(headline, field), SHORT_NAMES[field]
        if not isinstance(value, dict):
            out[prefix] = value
            continue
        for name, inner in value.items():
            if isinstance(inner, dict):  # val_accuracy: experiment → method → accuracy
                out.update({f"{prefix}.{name}.{m}": v for m, v in inner.items()})
            elif inner is None:
                out[f"{prefix}.{name}"] = None
            else:
                out.update({f"{prefix}.{name}{end}": v for end, v in _ends(inner)})
    return out


def _ends(value: Eta1) -> list[tuple[str, float | None]]:
    ends = [("", value.value), (".low", value.low), (".high", value.high)]
    return ends + [(".ctl_low", value.ctl_low), (".ctl_high", value.ctl_high)]


def read_summary(path: str | Path) -> Headline:
    """metrics/summary.json (`summary_keys`' flat short names) back as the `Headline` record; a missing file names
    the stage that writes it, a stale one (a key it lacks) the key."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing; run the stage that writes it first: dvc repro report")
    flat = json.loads(path.read_text())
    data: dict = {}
    for field, prefix in SHORT_NAMES.items():
        if prefix in flat:
            data[field] = flat[prefix]
            continue
        nested: dict = {}
        for key, value in flat.items():  # the file's order: the methods' as the run listed them
            if not key.startswith(prefix + "."):
                continue
            name, _, rest = key[len(prefix) + 1 :].partition(".")
            if field == "val_accuracy":
                nested.setdefault(name, {})[rest] = value
            elif not rest:
                nested[name] = None if value is None else {"value": value}
            else:
                nested[name][rest] = value
        data[field] = nested
    try:
        return TypeAdapter(Headline).validate_python(data)
    except ValidationError as err:
        raise ConfigError(f"{path}: {describe(err.errors()[0], Headline)}; rerun dvc repro report") from None


def _eta1(answer: MethodAnswer, conditions: list[MethodAnswer]) -> Eta1:
    """``answer`` over ``conditions`` (itself, or the conditions it pools)."""
    return Eta1(answer.value, answer.low, answer.high, *controllers_bounds(conditions))


def eta1_text(value: Eta1 | None) -> str:
    """η̂1 [method's interval] and, where recorded, "these: [interval]" for these trained controllers, as the report
    and the README print it; '–' where the sweep has no such condition."""
    if value is None:
        return "– (not swept)"
    text = f"{fmt(value.value, 2)} [{fmt(value.low, 2)}, {fmt(value.high, 2)}]"
    if value.ctl_low is None or value.ctl_high is None:
        return text
    return f"{text}, these: [{fmt(value.ctl_low, 2)}, {fmt(value.ctl_high, 2)}]"


def headline_metrics(scope, run, findings: Findings) -> Headline:
    """``scope``, ``run``: the report's `Scope` and `Run`; the training condition is the findings' (the first
    location, the training weather, noise 0)."""
    seeds, methods, location = scope.grid.replicates, scope.grid.methods, scope.grid.locations[0]
    avoided = [cell for result in run.avoided for modes in result.cells.values() for cell in modes.values()]
    guarantees = [(c.estimate.theta, c.estimate.gamma) for c in [*run.cells, *avoided]]

    def pooled(method: str, where: str, answers: list[MethodAnswer]) -> Eta1:
        return _eta1(pooled_answer(method, where, answers), answers)

    swept = {
        (loc, w, x): condition_label(loc, w, x)
        for loc in scope.grid.locations
        for w in scope.grid.weathers
        for x in scope.grid.noises
    }
    training = swept.get((location, scope.train_weather, 0.0))  # None: not in this sweep

    def mine(method: str, where: set[str]) -> list[MethodAnswer]:
        """The method's answers at ``where``, all of them: the sweep's conditions, as the report's tables."""
        found = [a for a in run.safety.answers if a.method == method and a.condition in where]
        if len(found) != len(where):  # a condition left out would change what the number averages
            raise ValueError(f"metrics/safety.json: {method} has {len(found)} answers for {len(where)} conditions")
        return found

    def at_training(method: str) -> Eta1 | None:
        if training is None:
            return None
        found = mine(method, {training})
        return _eta1(found[0], found)

    def avoid_unknown(mode: Mode) -> dict[str, Eta1]:
        answers = {m: run.avoid.answer(m, UNKNOWN, mode) for m in methods}
        return {m: _eta1(a, [a]) for m, a in answers.items()}

    return Headline(
        eta1_training_condition={m: at_training(m) for m in methods},
        eta1_training_location={
            m: pooled(m, location, mine(m, {v for k, v in swept.items() if k[0] == location})) for m in methods
        },
        eta1_all_sweep_cells={m: pooled(m, "every cell", mine(m, set(swept.values()))) for m in methods},
        avoid_unknown_off=avoid_unknown(Mode.OFF),
        avoid_unknown_on=avoid_unknown(Mode.ON),
        avoid_unknown_calibrated=avoid_unknown(Mode.CALIBRATED),
        theta=max(theta for theta, _ in guarantees),
        gamma=max(gamma for _, gamma in guarantees),
        n_replicates=len(seeds),
        val_accuracy={
            e: {m: sum(run.trained[e, m, r].val_accuracy for r in seeds) / len(seeds) for m in methods}
            for e in scope.experiments
        },
        findings_supported=findings.supported,
    )


def headline_table(headline: Headline, params: dict) -> str:
    """The headline as a markdown table, methods as columns; ``params``: params.yaml's sweep (what each row
    averages)."""
    location, weather = params["locations"][0], params["train_weather"]
    weathers, noises, locations = len(params["weathers"]), len(params["noises"]), len(params["locations"])
    methods = list(headline.eta1_training_condition)
    rows = [
        (f"η̂1 at the training condition ({location}, {weather}, noise 0)", headline.eta1_training_condition),
        (f"η̂1 over {location}'s {weathers * noises} weather × noise conditions", headline.eta1_training_location),
        (
            f"η̂1 over all {locations * weathers * noises} sweep conditions ({locations} locations × {weathers} "
            f"weathers × {noises} noises)",
            headline.eta1_all_sweep_cells,
        ),
        ("collision avoidance, unknown conditions, warnings off", headline.avoid_unknown_off),
        ("… warnings on (the paper's thresholds)", headline.avoid_unknown_on),
        ("… warnings calibrated (fresh seeds)", headline.avoid_unknown_calibrated),
    ]
    body = [[name, *(eta1_text(v[m]) for m in methods)] for name, v in rows]
    body += [
        [f"validation accuracy, `{e}`", *(fmt(v[m], 3) for m in methods)] for e, v in headline.val_accuracy.items()
    ]
    header = f"mean over {headline.n_replicates} training replicates [interval for the method]"
    if any(v is not None and v.ctl_low is not None for _, row in rows for v in row.values()):
        header += ", these: [for these trained controllers]"
    return table([header, *methods], body)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="uqdrive headline",
        description="Print metrics/summary.json's headline numbers as the markdown table the README and report hold.",
    )
    parser.add_argument("summary", type=Path, nargs="?", default=Path("metrics/summary.json"), help="the summary file")
    parser.add_argument(
        "--params", type=Path, default=Path("params.yaml"), help="the run's params (what each row averages)"
    )
    args = parser.parse_args(argv)
    headline = read_summary(args.summary)
    print(headline_table(headline, yaml.safe_load(args.params.read_text())))
    return 0
