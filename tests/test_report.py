"""The `report` stage: tables filled from the metrics files, figures embedded, clear error on a missing input."""

import json
import re

import numpy as np
import pytest

from uqdrive.data.frames import encode_png
from uqdrive.pipeline.report import Pooled, fmt, run_report

METHODS, WEATHERS, NOISES = ("mcd", "vi"), ("clear_noon", "rain"), (0.0, 0.05)


def markdown_rows(text: str, first_header: str) -> list[dict[str, str]]:
    """Rows of the markdown table whose header starts with ``first_header``, as dicts keyed by header."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {first_header} |"))
    headers = [h.strip() for h in lines[start].strip("|").split("|")]
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(headers, (c.strip() for c in line.strip("|").split("|")))))
    return rows


def write_run(root):
    """Metrics and figures shaped like a finished pipeline's (random values, fixed seed)."""
    rng = np.random.default_rng(0)
    (root / "params.yaml").write_text(f"scenarios: [straight, roundabout]\ntrain_weather: clear_noon\n"
                                      f"methods: {list(METHODS)}\nweathers: {list(WEATHERS)}\nnoises: {list(NOISES)}\n")
    png = encode_png(rng.integers(0, 255, (20, 30, 3), dtype=np.uint8))
    for method in METHODS:
        train = {"val_accuracy": rng.random(), "majority_baseline_accuracy": 0.5, "val_nll": 0.3, "val_ece": 0.02,
                 "val_brier": 0.1, "train_frames": 100, "seed": 0, "dropout_p1": 0.1, "dropout_p2": 0.09,
                 "dropout_p3": 0.08, "posterior_sigma_mean": 0.01, "diagnostics": f"{method} diagnostics"}
        (root / "metrics/train").mkdir(parents=True, exist_ok=True)
        (root / f"metrics/train/{method}.json").write_text(json.dumps(train))
        (root / "plots/train").mkdir(parents=True, exist_ok=True)
        (root / f"plots/train/{method}_curve.png").write_bytes(png)
    summary = {m: {w: {f"noise{x}": {"eta1": rng.random(), "eta1_low": 0.1, "eta1_high": 0.9, "theta": 0.25,
                                     "gamma": 0.05, "n": 19, "scheme": "clopper_pearson", "base_seed": 100000,
                                     "collision_rate": rng.random(), "off_road_rate": 0.0,
                                     "mean_lateral_deviation": 0.2} for x in NOISES} for w in WEATHERS} for m in METHODS}
    (root / "metrics/safety.json").write_text(json.dumps(summary))
    evaluated = {m: {w: {f"noise{x}": {"frames": 50, "accuracy": rng.random(), "nll": 0.4, "ece": rng.random(),
                                       "brier": 0.2, "mean_mutual_information": rng.random(), "mean_eta2": 0.97,
                                       "auroc_mi": rng.random(), "auroc_one_minus_eta2": None,
                                       "hmc_tv_distance": rng.random(), "hmc_argmax_agreement": rng.random(),
                                       "hmc_mi_spearman": None if m == "vi" else rng.random()}
                         for x in NOISES} for w in WEATHERS} for m in METHODS}
    (root / "metrics/evaluate.json").write_text(json.dumps(evaluated))
    cell = {"eta1_low": 0.1, "eta1_high": 1.0, "n": 19, "full_speed_fraction": 0.9, "collision_rate": 0.0,
            "warning0_runs": 1, "warning1_runs": 2, "warning2_runs": 3,
            "thresholds": {"delta1": 0.7, "delta2": 0.6, "tau": 0.45}}
    check = {"agreement": 1.0}
    avoided = {m: {c: {mode: {**cell, "eta1": rng.random(), "autonomy": rng.random()} for mode in ("off", "on", "calibrated")}
                   for c in ("known", "unknown")} for m in METHODS}
    for m in METHODS:
        avoided[m]["calibration"] = {"target": 0.6, "feasible": True, "delta1": 1.0, "delta2": 1.0, "tau": 0.45,
                                     "replay_check": {"known": check, "unknown": check}}
    (root / "metrics/avoid.json").write_text(json.dumps(avoided))
    (root / "plots/safety/summary").mkdir(parents=True)
    (root / "plots/safety/summary/hexbin_noise0.0.png").write_bytes(png)  # the noise-0.05 figure is missing
    return summary, evaluated, avoided


def test_report_tables_hold_the_metrics_files_numbers(stage_config, tmp_path):
    summary, evaluated, avoided = write_run(tmp_path)
    result = run_report(stage_config("report"))
    text = (tmp_path / "reports/report.md").read_text()
    rows = markdown_rows(text, "method | weather")
    assert len(rows) == len(METHODS) * len(WEATHERS) * len(NOISES)
    for row in rows:
        cell = summary[row["method"]][row["weather"]][f"noise{float(row['noise'])}"]
        assert row["η̂1"] == fmt(cell["eta1"]) and row["collision"] == fmt(cell["collision_rate"])
        assert row["interval"] == f"[{fmt(cell['eta1_low'])}, {fmt(cell['eta1_high'])}]" and row["n"] == "19"
    assert [r["paper η̂1"] for r in rows if (r["method"], r["weather"], r["noise"]) == ("mcd", "clear_noon", "0")] == [
        "1.00 (the only perfect score)"]
    pooled = {(r["method"], r["noise"]): r for r in markdown_rows(text, "method | noise")}
    cells = [summary["vi"][w]["noise0.0"] for w in WEATHERS]
    k = sum(round(c["eta1"] * 19) for c in cells)
    assert pooled[("vi", "0")]["η̂1 all weathers"].startswith(fmt(k / 38))
    assert f"- Offline safety, vi over all weathers: ours {fmt(k / 38, 2)}" in text
    vi_unknown_on = avoided["vi"]["unknown"]["on"]["eta1"]
    assert f"- Collision avoidance, vi, unknown conditions, warnings on: ours {fmt(vi_unknown_on, 2)}" in text
    training = {r["method"]: r for r in markdown_rows(text, "method | val accuracy")}
    assert training["vi"]["val accuracy"] == fmt(json.loads((tmp_path / "metrics/train/vi.json").read_text())["val_accuracy"])
    assert training["mcd"]["diagnostics"] == "mcd diagnostics"
    agreement = {r["method"]: r for r in markdown_rows(text, "method | mean TV to HMC")}
    mcd_cells = [evaluated["mcd"][w][f"noise{x}"] for w in WEATHERS for x in NOISES]
    assert agreement["mcd"]["mean TV to HMC"] == fmt(sum(c["hmc_tv_distance"] for c in mcd_cells) / 4)
    assert agreement["mcd"]["worst condition TV"] == fmt(max(c["hmc_tv_distance"] for c in mcd_cells))
    assert agreement["vi"]["MI Spearman ρ"] == "–"
    held_out = markdown_rows(text, "method | weather | noise | frames")
    assert len(held_out) == len(rows)
    for row in held_out:
        cell = evaluated[row["method"]][row["weather"]][f"noise{float(row['noise'])}"]
        assert (row["accuracy"], row["ECE"], row["mean MI"], row["AUROC MI"], row["AUROC 1 − η2"]) == (
            fmt(cell["accuracy"]), fmt(cell["ece"]), fmt(cell["mean_mutual_information"]), fmt(cell["auroc_mi"]), "–")
    avoid_rows = markdown_rows(text, "method | condition")
    assert len(avoid_rows) == len(METHODS) * 2 * 3
    for row in avoid_rows:
        cell = avoided[row["method"]][row["condition"]][row["warnings"]]
        assert (row["η̂1"], row["autonomy"], row["runs with w0 / w1 / w2"]) == (
            fmt(cell["eta1"]), fmt(cell["autonomy"]), "1 / 2 / 3")
    assert [r["paper"] for r in avoid_rows if (r["method"], r["condition"], r["warnings"]) == ("vi", "unknown", "on")] == [
        "0.90 ± 0.05"]
    assert "| profile | `tiny` |" in text and "Figure missing: `plots/safety/summary/hexbin_noise0.05.png`" in text

    html = (tmp_path / "reports/report.html").read_text()
    assert result["figures"] == 3 and html.count('src="data:image/png;base64,') == 3  # agreement_hmc.png: missing
    assert not re.search(r'src="(?!data:)', html)  # self-contained: no file links left


def test_missing_metrics_file_names_it(stage_config, tmp_path):
    write_run(tmp_path)
    (tmp_path / "metrics/safety.json").unlink()
    with pytest.raises(FileNotFoundError, match="metrics/safety.json is missing"):
        run_report(stage_config("report"))
    assert not (tmp_path / "reports").exists()


@pytest.mark.parametrize("rates", [(1.0, 1.0, 1.0), (1.0, 0.9, 0.5), (0.99, 0.6, 0.05), (0.5, 0.5, 0.5)])
def test_pooled_interval_covers_the_mean_rate_of_independent_cells(rates):
    """Hoeffding's guarantee for cells with different known rates: P(|pooled − mean rate| > θ) ≤ γ,
    checked on 2000 simulated sweeps (slack: 3 binomial standard errors of the miss rate)."""
    gamma, n, reps = 0.05, 19, 2000
    rng = np.random.default_rng(1)
    counts = rng.binomial(n, rates, size=(reps, len(rates)))
    misses = 0
    for row in counts:
        pooled = Pooled.of([{"eta1": k / n, "n": n} for k in row], gamma)
        misses += abs(pooled.value - np.mean(rates)) > pooled.theta
    assert misses / reps <= gamma + 3 * np.sqrt(gamma * (1 - gamma) / reps)
