"""The report's sections on the paper's two experiments, each with its own controllers trained once per replicate:
offline safety at the roundabout over weather × noise × location, and collision avoidance on the obstacle road;
and the fidelity table that puts every number the paper reports beside the method-level answers."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from uqdrive.analysis import paper
from uqdrive.analysis.method_answers import UNKNOWN, AvoidSummary, MethodAnswer, SafetySummary, pooled_answer
from uqdrive.avoid.results import AvoidResult, Mode
from uqdrive.models.trained_record import TrainMetrics
from uqdrive.records import read_record
from uqdrive.report.document import Report, fmt, table
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.safety.rollout_metrics import METRICS
from uqdrive.stage_schemas import training_stage

STOPPING_NOTE = "a car at 8 m/s needs 5.3 m to stop at 6 m/s²"
TRAINING_REFERENCE = {
    "mcd": "dropout rates " + ", ".join(f"{p:g}" for p in paper.DROPOUT_RATES),
    "hmc": "10 leapfrog steps (as here)",
}
TRAINING_HEADERS = [
    "experiment",
    "method",
    "classes",
    "val accuracy (mean)",
    "per replicate",
    "majority class",
    "NLL per replicate",
    "ECE per replicate",
    "train frames",
    "diagnostics (first replicate)",
    "paper",
]
HMC_KEYS = (
    "fs_rhat_share_ok",
    "fs_rhat_target_share",
    "fs_rhat_median",
    "fs_ess_bulk_min",
    "fs_ess_tail_min",
    "mi_rhat_max",
    "mi_ess_bulk_min",
    "between_chain_mi_share",
    "train_seconds",
)


@dataclass(frozen=True)
class Run:
    """What the report reads, as records: training metrics by (experiment, method, replicate), the safety cells and
    their method-level summary, the avoid results and theirs."""

    trained: dict[tuple[str, str, int], TrainMetrics]
    classes: dict[str, int]
    cells: list[SafetyCell]
    safety: SafetySummary
    avoided: list[AvoidResult]
    avoid: AvoidSummary

    def answer_cell(self, answer: MethodAnswer) -> str:
        """Value [interval] and each replicate's estimate."""
        each = " / ".join(fmt(e, 2) for e in answer.estimates)
        return f"{fmt(answer.value, 2)} [{fmt(answer.low, 2)}, {fmt(answer.high, 2)}] ({each})"


def _per_replicate(values: list[float], digits: int = 3) -> str:
    return " / ".join(fmt(v, digits) for v in values)


def training_section(report: Report, run: Run, experiments: list[str], methods: list[str], seeds: list[int]) -> None:
    rows, sampled = [], []
    for experiment in experiments:
        for method in methods:
            trained = [run.trained[experiment, method, r] for r in seeds]
            accuracy = [m.val_accuracy for m in trained]
            rows.append(
                [
                    experiment,
                    method,
                    str(run.classes[experiment]),
                    fmt(sum(accuracy) / len(accuracy)),
                    _per_replicate(accuracy),
                    fmt(trained[0].majority_baseline_accuracy),
                    _per_replicate([m.val_nll for m in trained]),
                    _per_replicate([m.val_ece for m in trained]),
                    str(trained[0].train_frames),
                    trained[0].diagnostics,
                    TRAINING_REFERENCE.get(method, "–"),
                ]
            )
            for r, m in zip(seeds, trained):
                if m.get("fs_rhat_share_ok") is not None:
                    sampled.append([experiment, method, str(r), *(fmt(m.get(k), 2) for k in HMC_KEYS)])
    report.add(
        '## Controllers\n\nOne controller per experiment × method × training replicate (seed), as the paper ("neurons '
        'equal to the number of classes (variable per experiment)"), each replicate with its own MCD trunk. Validation '
        "frames are whole held-out episodes of the training collection (training weather, no noise)."
    )
    report.add(table(TRAINING_HEADERS, rows))
    if sampled:
        report.add(
            "Convergence of the sampled posteriors in function space (rank-normalised split-R̂ and ESS from ArviZ over "
            "the predictive class probabilities of validation frames, and over each frame's mutual information):"
        )
        headers = ["experiment", "method", "replicate", "share R̂ ≤ 1.1", "target", "median R̂", "min bulk ESS"]
        headers += ["min tail ESS", "MI R̂ max", "MI min bulk ESS", "between-chain share of MI", "train seconds"]
        report.add(table(headers, sampled))


def learning_curves_section(report: Report, experiments: list[str], methods: list[str], seeds: list[int]) -> None:
    """Last in the report: how training went matters less than what the controllers did."""
    report.add("## Learning curves\n\nValidation accuracy against the training step, the first replicate.")
    for experiment in experiments:
        for method in methods:
            report.figure(
                report.root / "plots" / experiment / "train" / method / f"seed{seeds[0]}_curve.png",
                f"{experiment} · {method} learning curve (replicate seed{seeds[0]})",
            )


def guarantee_note(family_size: int, gamma: float, what: str) -> str:
    """Which guarantee a table carries: each cell on its own, or all of them at once."""
    if family_size > 1:
        return (
            f"**Guarantee: family-wise.** γ was spread over the {family_size} {what} (γ = {gamma:g} each): every "
            "cell's interval holds at once with probability ≥ 1 − γ·m."
        )
    return (
        f"**Guarantee: per cell.** Each cell's interval holds with probability ≥ 1 − {gamma:g} on its own; over many "
        "cells a few are expected to miss (set `family_wise: true` for all at once)."
    )


def safety_section(report: Report, run: Run, methods: list[str], conditions: list[tuple[str, str, float]]) -> None:
    cell = run.cells[0].estimate
    report.add(f"""
## Offline safety: η1 over weather × sensor noise × location

η1 is the probability that a closed-loop run of an `offline` controller stays in the safe set: the car's body
keeps to its lane until the first exit. Every cell drives the same rollout seeds (paired comparison); each
replicate's cell: η̂1 from {cell.n} rollouts ({cell.scheme}, θ = {cell.theta:g}). The table gives each method's
answer over its replicates: the mean of the replicates' η̂1 with an interval for the method's η1 that includes the
spread between training runs ({run.safety.answers[0].interval}, at γ = {run.safety.answers[0].gamma:g}), then each
replicate's η̂1. With few replicates that interval is wide: it is how much the training runs leave unknown.
{guarantee_note(run.safety.family_size, run.safety.cell_gamma, "cells of the sweep")}""")
    rows = []
    for method in methods:
        for location, weather, noise in conditions:
            answer = run.safety.answer(method, location, weather, noise)
            members = [c for c in run.cells if c.method == method and c.condition == (location, weather, noise)]
            rows.append(
                [
                    method,
                    location,
                    weather,
                    f"{noise:g}",
                    fmt(answer.value, 2),
                    f"[{fmt(answer.low, 2)}, {fmt(answer.high, 2)}]",
                    _per_replicate(answer.estimates, 2),
                    _per_replicate([c.left_corridor_rate for c in members], 2),
                    fmt(max((c.max_corridor_use for c in members if c.max_corridor_use is not None), default=None), 2),
                ]
            )
    headers = ["method", "location", "weather", "noise", "η̂1", "method interval", "per replicate", "left lane"]
    report.add(table([*headers, "corridor use"], rows))
    rollout_metrics_table(report, run.cells, methods, conditions)
    for location in dict.fromkeys(c[0] for c in conditions):
        for noise in dict.fromkeys(c[2] for c in conditions):
            report.figure(
                report.root / "plots" / "safety" / "summary" / f"hexbin_{location}_noise{noise!r}.png",
                f"Visited positions per method × weather at {location}, sensor noise {noise:g}, every replicate; "
                "reference route dashed, safe-set boundaries red (the paper's offline-safety figure)",
            )


def rollout_metrics_table(
    report: Report, cells: list[SafetyCell], methods: list[str], conditions: list[tuple[str, str, float]]
) -> None:
    """Every per-rollout metric of the registry (`uqdrive.safety.rollout_metrics.METRICS`) as each cell summarised
    it, one value per replicate ('–': no rollout of the cell measured it)."""
    rows = [
        [
            method,
            location,
            weather,
            f"{noise:g}",
            *(_per_replicate([getattr(c, m.name) for c in members], 2) for m in METRICS),
        ]
        for method in methods
        for location, weather, noise in conditions
        for members in [[c for c in cells if c.method == method and c.condition == (location, weather, noise)]]
    ]
    report.add("How each cell's rollouts went, per replicate (the cell's summary of what every rollout recorded):")
    report.add(table(["method", "location", "weather", "noise", *(m.label for m in METRICS)], rows))


def avoid_section(report: Report, run: Run, methods: list[str]) -> None:
    first = run.avoided[0]
    known = first.cells[first.conditions[0]][Mode.OFF].estimate
    report.add(f"""
## Real-time collision avoidance

The `avoid` controllers on the obstacle road: a stationary car 40 m ahead in the ego lane. A run is safe when it
never collides nor leaves the road and either passes the obstacle or stops after a hand-over within the horizon.
`known`: the training weather; every unknown condition is its own cell (η̂1 from {known.n} runs per replicate), the
unknown mixture their mean. Warnings `off`, `on` (δ1 = {paper.WARNING_THRESHOLDS["delta1"]}, δ2 =
{paper.WARNING_THRESHOLDS["delta2"]}, τ = {paper.WARNING_THRESHOLDS["tau"]}, the paper's); on fresh seeds the
calibration never saw, `fresh_off` and `calibrated` (thresholds certified by Learn-then-Test). Each row: the
method's answer over its replicates, as in the offline-safety table. The paper's numbers are for
{paper.AVOID_METHOD.upper()}.
{guarantee_note(run.avoid.family_size, known.gamma, "cells of each controller")}""")
    rows = []
    for method in methods:
        mine = [r for r in run.avoided if r.method == method]
        for condition in [*first.conditions, UNKNOWN]:
            for mode in Mode:
                answer = run.avoid.answer(method, condition, mode)
                cells = [r.cells[condition][mode] for r in mine] if condition != UNKNOWN else []
                autonomy = [r.unknown[mode].autonomy for r in mine] if not cells else [c.autonomy for c in cells]
                rows.append(
                    [
                        method,
                        condition,
                        mode,
                        fmt(answer.value, 2),
                        f"[{fmt(answer.low, 2)}, {fmt(answer.high, 2)}]",
                        _per_replicate(answer.estimates, 2),
                        _per_replicate(autonomy, 2),
                        _per_replicate([c.collision_rate for c in cells], 2) if cells else "",
                    ]
                )
    headers = ["method", "condition", "warnings", "η̂1", "method interval", "per replicate", "autonomy per replicate"]
    report.add(table([*headers, "collisions per replicate"], rows))
    calibration_section(report, run, methods)


def _calibration_row(method: str, result: AvoidResult) -> list[str]:
    cal, fresh = result.calibration.certificate, result.calibration.fresh_seed_check
    middle = "middle tier guaranteed" if cal.middle_guaranteed else "middle tier not guaranteed"
    return [
        method,
        str(result.replicate),
        f"{cal.delta1:g} / {cal.delta2:g} / {cal.tau:g}",
        f"{cal.autonomy_target:g}",
        f"{cal.certified} of {cal.candidates}",
        fmt(cal.replayed["eta1_unknown"], 2),
        f"{fmt(fresh.known_autonomy, 2)} ({fresh.check.runs})",
        f"{fmt(fresh.check.p_value, 3)} for ≥ {fresh.check.target:g} at {fmt(fresh.check.level, 4)} "
        f"({'met' if fresh.check.target_met else 'not met'})",
        fmt(fresh.unknown_eta1, 2),
        f"{cal.rule.tier.scheme}, error {fmt(cal.rule.tier.wrong_tier_error, 4)}, {middle}",
    ]


def calibration_section(report: Report, run: Run, methods: list[str]) -> None:
    rows, uncaught = [], []
    for method in methods:
        for result in [r for r in run.avoided if r.method == method]:
            rows.append(_calibration_row(method, result))
            uncaught += [
                f"- **{method} seed{result.replicate}, {v.condition}**: η̂1 {fmt(v.eta1_off, 2)} without "
                f"warnings and no threshold on the grid saves any of its failures (median lowest η2 per run "
                f"{fmt(v.min_eta2_median, 2)}, median highest MI {fmt(v.max_mutual_information_median, 2)} nats)"
                for v in result.calibration.uncaught_variants
            ]
    guarantees = {r.calibration.certificate.guarantee.split(" (Learn-then-Test")[0] for r in run.avoided}
    report.add(
        "Calibration (beyond the paper), by Learn-then-Test: each candidate (δ1, δ2, τ) is tested, on the replayed "
        'warnings-off runs, against the null "its known-condition hand-over rate exceeds 1 − target" (exact binomial '
        "p-values), along a sequence fixed in advance (family-wise error ≤ γ over the whole grid); among the "
        "certified, the one with the most replayed unknown-condition safety. The replay runs the deployed rule itself "
        "(its tier test at its own θ, γ and looks on the recorded draw streams) and is exact up to a run's first "
        "warning action. The closed-loop claim is the fresh-seed test: one exact binomial test, fixed in advance, of "
        "known-condition autonomy ≥ its target on the calibrated cell's fresh known-condition runs ('met': rejected "
        "at the calibration's γ split over the pipeline's controllers; sized for power 0.8 at autonomy 0.95). "
        "A tier pair closer than 2θ leaves the middle tier (warning 1) without a guarantee. "
        "What the calibrations certified:\n\n" + "\n".join(f"- {g}" for g in sorted(guarantees))
    )
    headers = ["method", "replicate", "δ1 / δ2 / τ", "autonomy target", "certified candidates", "replayed unknown η̂1"]
    headers += ["fresh seeds: known autonomy (runs)", "exact test of autonomy ≥ target: p", "fresh seeds: unknown η̂1"]
    report.add(table([*headers, "deployed tier rule"], rows))
    report.add("Conditions that no threshold catches:\n\n" + ("\n".join(uncaught) if uncaught else "- none"))
    report.figure(
        report.root / "plots" / "avoid" / "summary" / "coll_avoid_main.png",
        "Paths coloured by mutual information, per method, every replicate (the paper's Figure coll_avoid_main)",
    )
    name = f"{methods[0]}-seed{run.avoided[0].replicate}"
    for figure, caption in (
        ("warnings.png", "η2 and mutual information against the distance to the obstacle, thresholds drawn"),
        ("tradeoff.png", "unknown-condition safety against known autonomy over the candidates; certified filled"),
    ):
        report.figure(report.root / "plots" / "avoid" / name / figure, f"{name}: {caption}")


def _overlap(low: float, high: float, reference: float) -> bool:
    """Whether our interval and the paper's (its value ± θ) overlap: both could hold the same η1."""
    return max(low, reference - paper.THETA) <= min(high, reference + paper.THETA)


def _pooled(answers: list[MethodAnswer]) -> tuple[float, float, float]:
    """The uniform mixture of conditions (the paper's "across all weathers"), over the replicates."""
    pooled = pooled_answer(answers[0].method, "pooled", answers)
    return pooled.value, pooled.low, pooled.high


def fidelity_section(report: Report, run: Run, methods: list[str], weathers: list[str], location: str) -> None:
    """Every number the paper reports beside the method-level answers, and whether the intervals overlap."""
    rows: list[list[str]] = []
    widths: list[float] = []

    def add(claim: str, reference: float, value: float, low: float, high: float) -> None:
        same = _overlap(low, high, reference)
        widths.append(high - low)
        ours = f"{fmt(value, 2)} [{fmt(low, 2)}, {fmt(high, 2)}]"
        rows.append([claim, f"{reference:.2f} ± {paper.THETA:g}", ours, "yes" if same else "**no**"])

    def offline(method: str, names: list[str]) -> list[MethodAnswer]:
        return [run.safety.answer(method, location, w, 0.0) for w in names if w in weathers]

    for method, reference in paper.OFFLINE_ALL_WEATHERS.items():
        if method in methods:
            add(f"offline, {method}, all weathers", reference, *_pooled(offline(method, weathers)))
    dry = [w for w in weathers if w != "rain"]
    if "mcd" in methods and dry:  # a sweep of rain alone has no claim to set beside the paper's
        add(
            "offline, mcd, all weathers but rain",
            paper.OFFLINE_WITHOUT_RAIN["mcd"],
            *_pooled(offline("mcd", dry)),
        )
        if "clear_noon" in weathers:
            answer = run.safety.answer("mcd", location, "clear_noon", 0.0)
            add(
                "offline, mcd, training weather",
                paper.OFFLINE_TRAINING_WEATHER["mcd"],
                answer.value,
                answer.low,
                answer.high,
            )
    method = paper.AVOID_METHOD
    if method in methods:
        for mode, reference in (("off", paper.AVOID_UNKNOWN_OFF), ("on", paper.AVOID_UNKNOWN_ON)):
            a = run.avoid.answer(method, UNKNOWN, mode)
            add(f"avoid, {method}, unknown conditions, warnings {mode}", reference, a.value, a.low, a.high)
        a = run.avoid.answer(method, run.avoided[0].conditions[0], "on")
        add(f"avoid, {method}, known condition, warnings on", paper.AVOID_KNOWN_ON, a.value, a.low, a.high)
        autonomy = [r.cells[r.conditions[0]][Mode.ON].autonomy for r in run.avoided if r.method == method]
        rows.append(
            [
                f"avoid, {method}, known condition, autonomy",
                '1.00 ("full autonomy")',
                _per_replicate(autonomy, 2) + " (per replicate)",
                "yes" if min(autonomy) == 1 else "**no**",
            ]
        )
    report.add(
        f"## Beside the paper\n\nAt {location}, noise 0; ours is the method's answer over its replicates (mean, and "
        "the interval that includes the spread between training runs). Overlap: our interval and the paper's value "
        "± θ share a point (both could hold the same η1). The paper drove one network per method in CARLA."
    )
    report.add(table(["claim", "paper", "ours [interval]", "overlap"], rows))
    report.add(overlap_note(rows, widths, len(run.safety.answers[0].estimates)))


def overlap_note(rows: list[list[str]], widths: list[float], replicates: int) -> str:
    """What a column of "yes" means: the intervals are wide, not the numbers alike."""
    overlapping = sum(row[3] == "yes" for row in rows[: len(widths)])
    return (
        f"{overlapping} of the {len(widths)} η1 rows overlap. Overlap means only that this run cannot tell our method "
        f"from the paper's number: with {replicates} training replicates the method intervals span "
        f"{fmt(sum(widths) / len(widths), 2)} of [0, 1] on average (the spread between training runs is in them), so "
        "a 'yes' is no agreement. What these trained controllers did is decided in the findings above."
    )


def read_train_metrics(metrics_dir: Path, experiments: list[str], methods: list[str], seeds: list[int]) -> dict:
    """Every controller's training metrics by (experiment, method, replicate)."""
    return {
        (e, m, r): read_record(TrainMetrics, metrics_dir / e / "train" / m / f"seed{r}.json", training_stage(e, m))
        for e in experiments
        for m in methods
        for r in seeds
    }


def conditions_of(locations: list[str], weathers: list[str], noises: list[float]) -> list[tuple[str, str, float]]:
    return [(loc, w, float(x)) for loc in locations for w in weathers for x in noises]
