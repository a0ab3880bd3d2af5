"""The `report` stage: tables filled from the metrics files (typed records), findings first, figures embedded, a
clear error on a missing input."""

import dataclasses
import json
import re
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from uqdrive.acquire.acquisition import AcquiredAt, Acquisition, AcquisitionCheck, RoundSummary, before_after
from uqdrive.analysis.acquisition_summary import summarise_acquisition
from uqdrive.analysis.comparisons import avoid_comparisons, decide, safety_comparisons
from uqdrive.analysis.method_answers import summarise_avoid, summarise_methods
from uqdrive.analysis.method_claims import method_claims
from uqdrive.avoid.results import (
    ActionRecord,
    AvoidCell,
    AvoidResult,
    CalibrationSummary,
    Certificate,
    FreshSeedCheck,
    FreshSeedRecord,
    MixtureEstimate,
    Mode,
    RuleRecord,
    TierRecord,
)
from uqdrive.data.frames import encode_png
from uqdrive.data.preprocess import Preprocessed
from uqdrive.envelope.map_records import EnvelopeAxis, EnvelopeRegion, EnvelopeResult, EnvelopeSearch, GridCost
from uqdrive.models.heldout_eval import HeldoutCell, HeldoutTable
from uqdrive.models.trained_record import TrainMetrics
from uqdrive.pipeline.report_stage import run_report
from uqdrive.policy.draws import DrawSettings
from uqdrive.records import read_record, write_record
from uqdrive.report.document import fmt
from uqdrive.report.findings_text import claims_markdown, findings_markdown
from uqdrive.report.headline import read_summary
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.safety.rollout_metrics import METRICS
from uqdrive.uq.estimators import Estimate
from uqdrive.uq.verdict import Verdict

METHODS, WEATHERS, NOISES, SEEDS = ("mcd", "vi"), ("clear_noon", "rain"), (0.0, 0.05), (0, 1)
EXPERIMENTS, LOCATIONS, CONDITIONS = ("avoid", "offline"), ("roundabout", "roundabout_large"), ("known", "fog")
N = 19
RULE = RuleRecord(
    **dict(delta1=0.9, delta2=0.8, tau=0.45, theta=0.05, gamma=0.05, hold_s=1.0, samples=738),
    actions={f"warning{level}": ActionRecord(1.0 - level / 2, level == 2, level == 2) for level in range(3)},
    draws=DrawSettings(scheme="sequential"),
    tier=TierRecord("sequential", 0.9, 0.8, 0.05, 0.05, [8, 16, 32], 0.02, False),
)


def markdown_rows(text: str, first_header: str) -> list[dict[str, str]]:
    """Rows of the markdown table whose header starts with ``first_header``, as dicts keyed by header."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {first_header} |"))
    headers = [h.strip() for h in lines[start].strip("|").split("|")]
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(headers, (c.strip() for c in line.strip("|").split("|")))))
    return rows


def outcomes(rng: np.random.Generator, rate: float) -> str:
    return "".join("1" if s else "0" for s in rng.random(N) < rate)


def safety_cell(rng, method, seed, location, weather, noise) -> SafetyCell:
    safe = outcomes(rng, 0.2 if weather == "rain" and noise else 0.9)
    eta1 = safe.count("1") / N
    rates = dict(collision_rate=0.0, off_road_rate=0.0, left_corridor_rate=1 - eta1, reached_goal_rate=1.0)
    corridor = dict(max_corridor_use=float(rng.random() * 2), mean_corridor_use=0.3, mean_lateral_deviation=0.2)
    return SafetyCell(
        **dict(method=method, replicate=seed, experiment="offline", location=location, weather=weather, noise=noise),
        estimate=Estimate(eta1, max(0, eta1 - 0.25), min(1, eta1 + 0.25), N, 0.25, 0.05, "clopper_pearson", True),
        **dict(base_seed=100000, family_size=1, fixed_rollouts=N),
        **dict(rollouts=N, steps=100, seconds=1.0, **rates, **corridor, mean_eta2=0.9, mean_mutual_information=0.1),
        **dict(outcomes=safe, config_hash="x"),
    )


def avoid_cell(rng, mode) -> AvoidCell:
    safe = outcomes(rng, 0.8 if mode in ("on", "calibrated") else 0.4)
    eta1 = safe.count("1") / N
    seed = 300000 if mode in ("fresh_off", "calibrated") else 200000
    counts = {f"warning{lv}_{k}": 1 for lv in range(3) for k in ("frames", "runs")}
    return AvoidCell(
        estimate=Estimate(eta1, 0.0, 1.0, N, 0.25, 0.05, "clopper_pearson", True),
        **dict(handover_rate=0.1, autonomy=float(rng.random())),
        **dict(full_speed_fraction=0.9, collision_rate=1 - eta1, off_road_rate=0.0, passed_rate=eta1),
        **dict(timeout_before_obstacle_rate=0.0, handover_distance_min=10.0, handover_distance_median=12.5),
        **dict(handover_distances=[12.5], mean_steps=100.0, seconds=1.0, reused=False, **counts),
        **dict(terminations={"collision": 1}),
        **dict(family_size=1, fixed_rollouts=N, thresholds={"delta1": 0.7}, base_seed=seed, outcomes=safe),
    )


def avoid_result(rng, method, seed) -> AvoidResult:
    cells = {c: {m: avoid_cell(rng, m) for m in Mode} for c in CONDITIONS}
    unknown = {
        m: MixtureEstimate(cells["fog"][m].estimate.value, 0.0, 1.0, 0.3, 0.05, N, 0.5, "hoeffding") for m in Mode
    }
    certificate = Certificate(
        **dict(delta1=0.9, delta2=0.8, tau=0.45, feasible=True, certified=12, guarantee=f"{method} certified"),
        **dict(autonomy_target=0.8, max_certifiable_target=0.85, gamma=0.05, missed_limit=None, order="firing"),
        **dict(calibration_runs={"known": N, "fog": N}, learn_runs={"known": 0, "fog": 0}, candidates=729),
        replayed={"eta1_unknown": 0.6},
        rule=RULE,
        middle_guaranteed=False,
        refused={},
    )
    calibration = CalibrationSummary(
        certificate=certificate,
        fresh_seed_check=FreshSeedRecord(FreshSeedCheck(N, N, 0.8, 0.05, 0.8**N, True), 1.0, 0.9, 0.5, 300000),
        uncaught_variants=[
            {"condition": "fog", "eta1_off": 0.4, "min_eta2_median": 0.97, "max_mutual_information_median": 0.1}
        ]
        if method == "vi"
        else [],
        replay_check={},
    )
    return AvoidResult(
        **dict(
            method=method, replicate=seed, experiment="avoid", cells=cells, unknown=unknown, calibration=calibration
        ),
        **dict(
            warning=RULE, samples_per_frame=738, conditions=list(CONDITIONS), horizon_s=14.0, speed=8.0, seconds=1.0
        ),
    )


def envelope_result(rng, method) -> EnvelopeResult:
    """A map of two regions (one safe, one undecided), the rest of the record as the stage writes it."""
    regions = [
        EnvelopeRegion(
            **dict(name=f"r{i}", order=i, bounds={"noise": [0.1 * i, 0.1 * i + 0.1], "weather.blend": [0.0, 1.0]}),
            **dict(depth=1, volume=0.5, gamma=0.025, verdict=verdict, rollouts=int(rng.integers(10, 60))),
            **dict(safe_rollouts=5, eta1_hat=0.5, undecided_by=None if verdict == "safe" else "region_budget"),
        )
        for i, verdict in enumerate(("safe", "undecided"))
    ]
    certified = sum(r.rollouts for r in regions)
    return EnvelopeResult(
        **dict(method=method, replicate=0, experiment="offline", location="roundabout", weather="clear_noon"),
        axes=[EnvelopeAxis("noise", [0.0, 0.2]), EnvelopeAxis("weather.blend", [0.0, 1.0])],
        **dict(noise=0.0, blend={"from": "clear_noon", "to": "rain"}, threshold=0.9, gamma=0.05, theta=0.0),
        **dict(guarantee="family-wise", base_seed=400000, regions=regions),
        verdicts={"safe": 1, "unsafe": 0, "undecided": 1},
        volume={"safe": 0.5, "unsafe": 0.0, "undecided": 0.5},
        search=EnvelopeSearch(rollouts=8, failures=3, rounds=[8], points=[[0.1, 0.5]] * 8, outcomes="11100011"),
        rollouts={"search": 8, "certify": certified, "unread": 3, "total": 11 + certified},
        grid=GridCost(
            theta=0.05, cells=16, gamma_per_cell=0.003125, per_cell=1000, rollouts=16000, rollouts_per_cell_gamma=9000
        ),
        seconds=float(rng.random() * 100),
    )


def acquisition(rng, method, seed) -> Acquisition:
    """One controller's round 0 and 1 at the training cell and one flagged cell, 14 check seeds each."""
    cells, checks = ("roundabout-clear_noon-noise0.0", "roundabout_large-rain-noise0.0"), []
    for k in (0, 1):
        for cell in cells:
            safe = outcomes(rng, 0.3 + 0.5 * k)
            eta1 = safe.count("1") / len(safe)
            checks.append(AcquisitionCheck(method, seed, k, cell, eta1, eta1 / 2, 1.0, len(safe), 0.9, 0.7, 1.0, safe))
    rounds = [RoundSummary(0, 1.0, 0, 100, 0.8, [])]
    rounds.append(RoundSummary(1, 0.5, 60, 160, 0.82, [AcquiredAt(1, cell, 4, 30) for cell in cells]))
    compared = before_after(checks, cells[0], 0.1)
    return Acquisition(method, seed, "offline", 0.9, [cells[1]], rounds, checks, compared, cells[0], 0.1)


def write_run(root):
    """Metrics and figures shaped like a finished pipeline's (random values, fixed seed), written as records."""
    rng = np.random.default_rng(0)
    (root / "params.yaml").write_text(
        f"experiments: {list(EXPERIMENTS)}\ntrain_weather: clear_noon\nheads: {list(METHODS)[1:]}\n"
        f"methods: {list(METHODS)}\nreplicates: {list(SEEDS)}\nweathers: {list(WEATHERS)}\nnoises: {list(NOISES)}\n"
        f"locations: {list(LOCATIONS)}\n"
    )
    png = encode_png(rng.integers(0, 255, (20, 30, 3), dtype=np.uint8))
    trained = {}
    for experiment in EXPERIMENTS:
        (root / f"metrics/{experiment}").mkdir(parents=True, exist_ok=True)
        preprocessed = Preprocessed(experiment, 7, 0.0, -0.5, 0.5, 100, 40, 0.3)
        write_record(root / f"metrics/{experiment}/preprocess.json", preprocessed)
        for method in METHODS:
            for seed in SEEDS:
                metrics = TrainMetrics(
                    **dict(method=method, val_accuracy=float(rng.random()), val_nll=0.3, val_ece=0.02, val_brier=0.1),
                    **dict(majority_baseline_accuracy=0.5, train_frames=100, val_frames=40, eval_samples=10, seed=seed),
                    train_seconds=1.0,
                    diagnostics=f"{method} diagnostics",
                )
                trained[experiment, method, seed] = metrics
                write_record(root / f"metrics/{experiment}/train/{method}/seed{seed}.json", metrics)
            (root / f"plots/{experiment}/train/{method}").mkdir(parents=True, exist_ok=True)
            (root / f"plots/{experiment}/train/{method}/seed0_curve.png").write_bytes(png)
            for seed in SEEDS:
                curve = "step,train_loss,val_accuracy\n1,2.0,0.5\n2,1.0,0.75\n"
                (root / f"plots/{experiment}/train/{method}/seed{seed}_curve.csv").write_text(curve)
    cells = [
        safety_cell(rng, m, r, loc, w, x)
        for m in METHODS
        for r in SEEDS
        for loc in LOCATIONS
        for w in WEATHERS
        for x in NOISES
    ]
    for cell in cells:
        write_record(root / f"metrics/safety/{cell.name}.json", cell)
    safety = summarise_methods(cells, METHODS)
    write_record(root / "metrics/safety.json", safety)
    results = [avoid_result(rng, m, r) for m in METHODS for r in SEEDS]
    for result in results:
        write_record(root / f"metrics/avoid/{result.method}-seed{result.replicate}.json", result)
    avoid = summarise_avoid(results, list(METHODS))
    write_record(root / "metrics/avoid.json", avoid)
    family = [*safety_comparisons(cells, list(METHODS), ("roundabout", "clear_noon", 0.0))]
    claims = method_claims(cells, results, list(METHODS), ("roundabout", "clear_noon", 0.0), 0.05, 0.1)
    findings = dataclasses.replace(decide([*family, *avoid_comparisons(results, list(METHODS))], 0.05), claims=claims)
    write_record(root / "metrics/findings.json", findings)
    evaluated = HeldoutTable(
        {
            m: {
                w: {
                    f"noise{x}": HeldoutCell(
                        **dict(frames=50, mistakes=5, accuracy=rng.random(), nll=0.4, ece=rng.random(), brier=0.2),
                        **dict(mean_mutual_information=rng.random(), mean_eta2=0.97, auroc_mi=rng.random()),
                        **dict(auroc_one_minus_eta2=None, auroc_note=None, hmc_tv_distance=rng.random()),
                        hmc_argmax_agreement=rng.random(),
                        hmc_mi_spearman=None if m == "vi" else rng.random(),
                    )
                    for x in NOISES
                }
                for w in WEATHERS
            }
            for m in METHODS
        }
    )
    write_record(root / "metrics/evaluate.json", evaluated)
    envelopes = [envelope_result(rng, m) for m in METHODS]
    for envelope in envelopes:
        write_record(root / f"metrics/envelope/{envelope.method}-seed0.json", envelope)
    (root / "plots/envelope/vi-seed0").mkdir(parents=True)
    (root / "plots/envelope/vi-seed0/map.png").write_bytes(png)  # mcd's map is missing
    (root / "plots/safety/summary").mkdir(parents=True)
    (root / "plots/safety/summary/hexbin_roundabout_noise0.0.png").write_bytes(png)  # the noise-0.05 one is missing
    acquired = summarise_acquisition("offline", [acquisition(rng, m, r) for m in METHODS for r in SEEDS], 0.05, 0.1)
    write_record(root / "metrics/acquisition.json", acquired)
    return trained, safety, avoid, findings, evaluated, envelopes, acquired


def test_report_tables_hold_the_metrics_files_numbers(stage_config, tmp_path):
    trained, safety, avoid, findings, evaluated, envelopes, acquired = write_run(tmp_path)
    result = run_report(stage_config("report"))
    text = (tmp_path / "reports/report.md").read_text()

    assert findings_markdown(findings) in text  # the findings, generated from the file, come before the tables
    assert text.index("## The paper's claims and what the run found") < text.index(findings_markdown(findings))
    assert text.index("**The paper's claims, for the method**") < text.index("**For these trained controllers**")
    assert text.index("**For these trained controllers**") < text.index("## Controllers")
    header = "claim (A safer than B), for the mean"
    claims = {r[header]: r for r in markdown_rows(text, header)}
    paper = [c.result for c in findings.claims if c.family == "paper"]
    assert set(claims) == {c.name for c in paper} and {c.name for c in paper} >= {
        "vi safer than mcd offline",
        "mcd safer without rain than in rain",
        "vi: warnings on safer than off, unknown conditions",
    }
    on = next(c for c in paper if c.name == "vi: warnings on safer than off, unknown conditions")
    assert (
        claims[on.name]["paper"] == "0.9 vs 0"
        and claims[on.name]["mean Δ̂ [interval]"].startswith(f"{on.estimate:+.2f} [")
        and claims[on.name]["verdict (mean)"].strip("*") == str(on.verdict)
    )
    signs = {r["claim, for q"]: r for r in markdown_rows(text, "claim, for q")}  # q: its own table, its own words
    assert signs[on.name]["runs that differ"].startswith(f"a training run of A beats its paired run of B in {on.ahead}")
    assert {c.family for c in findings.claims} == {"paper", "exploratory"}  # the synthetic cells record no margins
    assert findings.supported > 0  # rain with noise breaks both methods in every replicate (0.2 against 0.9)
    rows = markdown_rows(text, "method | location | weather")
    assert len(rows) == len(METHODS) * len(LOCATIONS) * len(WEATHERS) * len(NOISES)
    for row in rows:
        answer = safety.answer(row["method"], row["location"], row["weather"], float(row["noise"]))
        assert (
            row["η̂1"] == fmt(answer.value, 2)
            and row["method interval"] == f"[{fmt(answer.low, 2)}, {fmt(answer.high, 2)}]"
        )
        assert row["per replicate"] == " / ".join(fmt(e, 2) for e in answer.estimates)
    assert "**Guarantee: per cell.**" in text
    per_run = markdown_rows(text, "method | location | weather | noise | collisions")  # the registry's table
    assert len(per_run) == len(rows) and set(per_run[0]) >= {m.label for m in METRICS}
    written = [read_record(SafetyCell, p, "safety") for p in sorted((tmp_path / "metrics/safety").glob("*.json"))]
    for row in per_run:
        where = (row["location"], row["weather"], float(row["noise"]))
        members = sorted(
            (c for c in written if (c.method, c.condition) == (row["method"], where)), key=lambda c: c.replicate
        )
        assert row["collisions"] == " / ".join(fmt(c.collision_rate, 2) for c in members)
        assert row["median time to lane edge (s)"] == " / ".join("–" for _ in members)  # the synthetic cells: none
    fidelity = {r["claim"]: r for r in markdown_rows(text, "claim")}
    assert fidelity["offline, vi, all weathers"]["paper"] == "0.91 ± 0.05"
    vi_dry = [safety.answer("vi", "roundabout", w, 0.0) for w in WEATHERS]
    mean = np.mean([np.mean([a.estimates[r] for a in vi_dry]) for r in range(len(SEEDS))])
    assert fidelity["offline, vi, all weathers"]["ours [interval]"].startswith(fmt(mean, 2))
    on = avoid.answer("vi", "unknown mixture", "on")
    assert fidelity["avoid, vi, unknown conditions, warnings on"]["ours [interval]"] == (
        f"{fmt(on.value, 2)} [{fmt(on.low, 2)}, {fmt(on.high, 2)}]"
    )
    training = {(r["experiment"], r["method"]): r for r in markdown_rows(text, "experiment | method")}
    accuracy = [trained["avoid", "vi", r].val_accuracy for r in SEEDS]
    assert training[("avoid", "vi")]["val accuracy (mean)"] == fmt(np.mean(accuracy))
    assert training[("avoid", "vi")]["per replicate"] == " / ".join(fmt(a) for a in accuracy)
    assert training[("offline", "mcd")]["diagnostics (first replicate)"] == "mcd diagnostics"
    agreement = {r["method"]: r for r in markdown_rows(text, "method | mean TV to HMC")}
    mcd_cells = [evaluated.cell("mcd", w, x) for w in WEATHERS for x in NOISES]
    assert agreement["mcd"]["mean TV to HMC"] == fmt(sum(c.hmc_tv_distance for c in mcd_cells) / 4)
    assert agreement["vi"]["MI Spearman ρ"] == "–"
    held_out = markdown_rows(text, "method | weather | noise | frames")
    assert len(held_out) == len(METHODS) * len(WEATHERS) * len(NOISES)
    avoid_rows = markdown_rows(text, "method | condition")
    assert len(avoid_rows) == len(METHODS) * (len(CONDITIONS) + 1) * len(Mode)
    for row in avoid_rows:
        answer = avoid.answer(row["method"], row["condition"], row["warnings"])
        assert row["η̂1"] == fmt(answer.value, 2) and row["per replicate"] == " / ".join(
            fmt(e, 2) for e in answer.estimates
        )
    assert "**vi seed0, fog**: η̂1 0.40 without warnings and no threshold" in text
    assert "- vi certified" in text  # each calibration's guarantee in words
    assert "| profile | `tiny` |" in text and "| training replicates | seeds 0, 1" in text
    assert "Figure missing: `plots/safety/summary/hexbin_roundabout_noise0.05.png`" in text
    envelope_rows = {r["method"]: r for r in markdown_rows(text, "method | safe on average (box)")}
    for envelope in envelopes:
        row = envelope_rows[envelope.method]
        n = envelope.rollouts
        assert row["safe on average (box)"] == "1 (50%)" and row["undecided"] == "1 (50%)"
        assert row["unsafe on average"] == "0 (0%)"
        assert row["rollouts"] == f"8 + {n['certify']} + 3 = {n['total']}" and row["grid"] == "16000"
        assert row["seconds"] == fmt(envelope.seconds, 0)
    assert "weather.blend (clear_noon → rain) ∈ [0, 1]" in text
    assert "Figure missing: `plots/envelope/mcd-seed0/map.png`" in text
    method_rows = markdown_rows(text, "method | check cell | round")
    assert len(method_rows) == len(acquired.methods) == len(METHODS) * 2
    for row, gain in zip(method_rows, acquired.methods):
        assert (row["method"], row["check cell"], row["round"]) == (gain.method, gain.cell, "1")
        assert row["behaviour cloning"] == fmt(gain.behaviour_cloned) and row["acquired"] == fmt(gain.acquired)
        assert row["acquired safer?"].startswith(str(gain.claim.verdict))
        assert row["training cell within 0.1"] == ("undecided" if "clear_noon" in gain.cell else "—")
    controller_rows = markdown_rows(text, "controller | check cell | behaviour cloning")
    assert len(controller_rows) == len(METHODS) * len(SEEDS) * 2
    assert sum("(training)" in r["check cell"] for r in controller_rows) == len(METHODS) * len(SEEDS)

    flat = json.loads((tmp_path / "metrics/summary.json").read_text())  # short names: `dvc exp show`'s columns
    ends = ("", ".low", ".high", ".ctl_low", ".ctl_high")
    assert list(flat)[:6] == [*(f"eta1.train.mcd{end}" for end in ends), "eta1.train.vi"]
    headline = read_summary(tmp_path / "metrics/summary.json")
    assert (headline.theta, headline.gamma, headline.n_replicates) == (0.25, 0.05, len(SEEDS))
    trained_here = safety.answer("vi", "roundabout", "clear_noon", 0.0)
    assert (flat["eta1.train.vi"], flat["eta1.train.vi.low"], flat["eta1.train.vi.high"]) == (
        trained_here.value,
        trained_here.low,
        trained_here.high,
    )
    pooled = sum(round(e * trained_here.rollouts) for e in trained_here.estimates)  # these controllers' safe runs
    exact = stats.binomtest(pooled, trained_here.rollouts * len(SEEDS)).proportion_ci(1 - trained_here.gamma, "exact")
    assert (flat["eta1.train.vi.ctl_low"], flat["eta1.train.vi.ctl_high"]) == pytest.approx(
        (exact.low, exact.high), abs=1e-9
    )
    every = [a for a in safety.answers if a.method == "vi"]
    assert len(every) == len(LOCATIONS) * len(WEATHERS) * len(NOISES)  # the sweep's mean leaves no cell out
    per_replicate = [np.mean([a.estimates[r] for a in every]) for r in range(len(SEEDS))]
    assert headline.eta1_all_sweep_cells["vi"].value == pytest.approx(np.mean(per_replicate))
    at_roundabout = [a for a in every if a.condition.startswith("roundabout-")]
    per_replicate = [np.mean([a.estimates[r] for a in at_roundabout]) for r in range(len(SEEDS))]
    assert headline.eta1_training_location["vi"].value == pytest.approx(np.mean(per_replicate))
    assert flat["avoid.on.mcd"] == avoid.answer("mcd", "unknown mixture", "on").value
    assert flat["avoid.off.mcd.low"] == avoid.answer("mcd", "unknown mixture", "off").low
    assert flat["val_acc.avoid.vi"] == pytest.approx(np.mean(accuracy))
    per_method = [headline.eta1_training_location, headline.avoid_unknown_off, headline.avoid_unknown_calibrated]
    assert all(list(values) == list(METHODS) for values in per_method)
    assert list(headline.val_accuracy) == list(EXPERIMENTS)
    assert flat["findings"] == headline.findings_supported == findings.supported

    curves = (tmp_path / "plots/report/learning_curves.csv").read_text().splitlines()
    assert curves[0] == "panel,replicate,step,val_accuracy" and "offline · vi,seed1,2,0.75" in curves
    assert len(curves) == 1 + len(EXPERIMENTS) * len(METHODS) * len(SEEDS) * 2  # every controller's curve, once
    html = (tmp_path / "reports/report.html").read_text()
    figures = len(EXPERIMENTS) * len(METHODS) + 3  # learning curves, η1 chart, one hexbin, vi's map; the rest missing
    assert result.figures == figures and html.count('src="data:image/png;base64,') == figures
    assert not re.search(r'src="(?!data:)', html)  # self-contained: no file links left
    prose = re.sub(r"`[^`]*`", "", (tmp_path / "reports/report.md").read_text())
    assert not re.findall(r"<[a-z_]+>", prose)  # a placeholder such as <cell> outside code vanishes from the HTML


def test_a_missing_or_stale_metrics_file_is_one_line_naming_it(stage_config, tmp_path):
    write_run(tmp_path)
    (tmp_path / "metrics/safety.json").unlink()
    with pytest.raises(FileNotFoundError, match="metrics/safety.json is missing; .* dvc repro safety_summary"):
        run_report(stage_config("report"))
    (tmp_path / "again").mkdir()
    write_run(tmp_path / "again")
    path = tmp_path / "again/metrics/avoid/vi-seed1.json"
    stale = json.loads(path.read_text())
    del stale["calibration"]["certificate"]["guarantee"]  # written by older code
    path.write_text(json.dumps(stale))
    with pytest.raises(
        ValueError, match=r"vi-seed1.json: calibration.certificate.guarantee is required; rerun dvc repro avoid@vi-1"
    ):
        run_report(stage_config("report", f"paths.root={tmp_path}/again"))
    assert not (tmp_path / "reports").exists()


def test_an_undecided_claim_shows_both_estimands_and_the_runs_that_would_decide_it():
    """Every replicate at 1.00 on both sides: no run differs, the mean's betting interval is wide; the mean's row
    says how many training runs would decide it (simulated, these runs' spread / the worst), q's row its own words."""
    result = SimpleNamespace(
        name="hmc safer than mcd offline", estimate=0.0, low=-0.9, high=0.9, ahead=0, behind=0, rollouts=14,
        verdict=Verdict.UNDECIDED, sign_verdict=Verdict.UNDECIDED, margin=0.1, differing_runs_needed=19,
        runs_needed=61, runs_needed_worst=None, replicates=[0, 1, 2], level=0.0025, sign_level=0.0025,
        assumption="none beyond i.i.d. training runs",
    )  # fmt: skip
    claim = SimpleNamespace(family="paper", paper=None, a_rates=[1.0] * 3, b_rates=[1.0] * 3, pairs=14, result=result)
    text = claims_markdown(SimpleNamespace(claims=[claim], margin=0.1, alpha=0.05))
    row = markdown_rows(text, "claim (A safer than B), for the mean")[0]
    assert row["mean Δ̂ [interval]"] == "+0.00 [-0.90, +0.90]" and row["verdict (mean)"] == "undecided"
    assert row["runs needed: these runs' spread / worst"] == "61 / > 20,000"
    sign = markdown_rows(text, "claim, for q")[0]
    assert (
        sign["runs that differ"]
        == "a training run of A beats its paired run of B in 0 of 0 that differ (of 3), at 14 rollouts per run"
    )
    assert "Family: these 1 claims' mean and sign verdicts together, family-wise error ≤ 0.05" in text


def test_the_report_opens_with_the_answer_then_its_contents_and_ends_with_the_learning_curves(stage_config, tmp_path):
    """The first screen: the short answer (generated: its numbers are the records'), a contents list whose every
    link is a heading's anchor in the HTML, then the paper's claims; the learning curves last."""
    _, safety, _, findings, *_ = write_run(tmp_path)
    run_report(stage_config("report"))
    text = (tmp_path / "reports/report.md").read_text()
    headings = [line for line in text.splitlines() if line.startswith("## ")]
    assert headings[0] == "## The answer" and headings[1] == "## The paper's claims and what the run found"
    assert headings[-1] == "## Learning curves" and text.index("**Contents**") < text.index(headings[1])
    assert text.index("learning curve (replicate seed0)") > text.index("## Learning curves")
    opening = text[: text.index("**Contents**")]
    trained_here = safety.answer("mcd", "roundabout", "clear_noon", 0.0)
    assert f"mcd {fmt(trained_here.value, 2)} [{fmt(trained_here.low, 2)}, {fmt(trained_here.high, 2)}]" in opening
    assert f"{findings.supported} of {findings.comparisons} comparisons supported" in opening
    unsafe = [c for c in dict.fromkeys(a.condition for a in safety.answers) if "rain-noise0.05" in c]
    not_safe = opening.split("**Not safe by the point estimates**")[1].split("\n")[0]
    assert all(c in not_safe for c in unsafe)  # rain with noise breaks both methods
    html = (tmp_path / "reports/report.html").read_text()
    links = re.findall(r'<a href="#([^"]+)">', html)
    assert len(links) == len(headings) - 1  # every section but the answer above the list
    assert all(f'id="{anchor}"' in html for anchor in links), links
    assert not re.search(r"\bnan\b", text, re.IGNORECASE)


def test_a_group_of_findings_names_each_method_once_and_a_range_with_equal_ends_prints_one_number():
    """The old row said "(and 2 more alike; methods in all: hmc, mcd, vi)" of three findings; and "1.00–1.00"."""
    from uqdrive.report.findings_text import _group_row, span

    base = dict(low=0.2, high=1.0, p_value=1e-3, effect=0.8)
    finding = SimpleNamespace(**base)
    members = [SimpleNamespace(a=f"{m} known off", b=f"{m} fog off", finding=finding) for m in ("mcd", "vi", "hmc")]
    what, gain, _ = _group_row(members)
    assert what == "**known off** safer than fog off, for mcd, vi, hmc (3 findings)" and "more" not in what
    assert gain.startswith("+0.80 ") and span(0.999, 1.0) == "1.00" and span(0.5, 0.75) == "0.50–0.75"


def test_a_sweep_without_the_training_condition_says_so_in_the_headline(stage_config, tmp_path):
    """`dvc exp run -S weathers=[rain]` sweeps no training weather: its headline is null there, printed '–'."""
    write_run(tmp_path)
    run_report(stage_config("report", "weathers=[rain]"))
    flat = json.loads((tmp_path / "metrics/summary.json").read_text())
    assert [flat[f"eta1.train.{m}"] for m in METHODS] == [None] * len(METHODS)
    assert f"eta1.train.{METHODS[0]}.low" not in flat
    assert read_summary(tmp_path / "metrics/summary.json").eta1_training_condition == {m: None for m in METHODS}
    assert flat["eta1.loc.vi"] is not None
    text = (tmp_path / "reports/report.md").read_text()
    assert text.startswith("# uqdrive report\n\n**Profile tiny (the tests' sizes): shows that every stage runs")
    assert "**At the training condition** (roundabout-clear_noon-noise0.0): mcd – (not swept)" in text
