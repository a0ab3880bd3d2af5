"""The `report` stage: tables filled from the metrics files, figures embedded, clear error on a missing input."""

import json
import re

import numpy as np
import pytest

from uqdrive.data.frames import encode_png
from uqdrive.pipeline.report import run_report
from uqdrive.pipeline.report_document import fmt

METHODS, WEATHERS, NOISES = ("mcd", "vi"), ("clear_noon", "rain"), (0.0, 0.05)
EXPERIMENTS, LOCATIONS, MODES = ("avoid", "offline"), ("roundabout", "roundabout_large"), ("off", "on", "calibrated")


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


def write_run(root):
    """Metrics and figures shaped like a finished pipeline's (random values, fixed seed)."""
    rng = np.random.default_rng(0)
    (root / "params.yaml").write_text(
        f"experiments: {list(EXPERIMENTS)}\ntrain_weather: clear_noon\n"
        f"posteriors: {list(METHODS)}\nmethods: {list(METHODS)}\n"
        f"weathers: {list(WEATHERS)}\nnoises: {list(NOISES)}\nlocations: {list(LOCATIONS)}\n"
    )
    png = encode_png(rng.integers(0, 255, (20, 30, 3), dtype=np.uint8))
    for experiment in EXPERIMENTS:
        (root / f"metrics/{experiment}/train").mkdir(parents=True, exist_ok=True)
        (root / f"metrics/{experiment}/preprocess.json").write_text(json.dumps({"num_classes": 7}))
        for method in METHODS:
            train = {
                "val_accuracy": rng.random(),
                "majority_baseline_accuracy": 0.5,
                "val_nll": 0.3,
                "val_ece": 0.02,
                "val_brier": 0.1,
                "train_frames": 100,
                "seed": 0,
                "dropout_p1": 0.1,
                "dropout_p2": 0.09,
                "dropout_p3": 0.08,
                "posterior_sigma_mean": 0.01,
                "diagnostics": f"{method} diagnostics",
            }
            (root / f"metrics/{experiment}/train/{method}.json").write_text(json.dumps(train))
            (root / f"plots/{experiment}/train").mkdir(parents=True, exist_ok=True)
            (root / f"plots/{experiment}/train/{method}_curve.png").write_bytes(png)
    summary = {
        m: {
            loc: {
                w: {
                    f"noise{x}": {
                        "eta1": round(rng.random() * 19) / 19,
                        "eta1_low": 0.1,
                        "eta1_high": 0.9,
                        "theta": 0.25,
                        "gamma": 0.05,
                        "n": 19,
                        "scheme": "clopper_pearson",
                        "base_seed": 100000,
                        "collision_rate": rng.random(),
                        "off_road_rate": 0.0,
                        "left_corridor_rate": rng.random(),
                        "reached_goal_rate": 1.0,
                        "max_corridor_use": rng.random() * 2,
                        "mean_corridor_use": 0.3,
                        "mean_lateral_deviation": 0.2,
                    }
                    for x in NOISES
                }
                for w in WEATHERS
            }
            for loc in LOCATIONS
        }
        for m in METHODS
    }
    (root / "metrics/safety.json").write_text(json.dumps(summary))
    evaluated = {
        m: {
            w: {
                f"noise{x}": {
                    "frames": 50,
                    "accuracy": rng.random(),
                    "nll": 0.4,
                    "ece": rng.random(),
                    "brier": 0.2,
                    "mean_mutual_information": rng.random(),
                    "mean_eta2": 0.97,
                    "auroc_mi": rng.random(),
                    "auroc_one_minus_eta2": None,
                    "hmc_tv_distance": rng.random(),
                    "hmc_argmax_agreement": rng.random(),
                    "hmc_mi_spearman": None if m == "vi" else rng.random(),
                }
                for x in NOISES
            }
            for w in WEATHERS
        }
        for m in METHODS
    }
    (root / "metrics/evaluate.json").write_text(json.dumps(evaluated))
    cell = {
        "eta1_low": 0.1,
        "eta1_high": 1.0,
        "n": 19,
        "full_speed_fraction": 0.9,
        "collision_rate": 0.0,
        "passed_rate": 1.0,
        "timeout_before_obstacle_rate": 0.0,
        "handover_distance_median": 12.5,
        "warning0_runs": 1,
        "warning1_runs": 2,
        "warning2_runs": 3,
        "thresholds": {"delta1": 0.7, "delta2": 0.6, "tau": 0.45},
    }
    avoided = {
        m: {
            "cells": {
                c: {mode: {**cell, "eta1": rng.random(), "autonomy": rng.random()} for mode in MODES}
                for c in ("known", "fog", "white_van")
            },
            "unknown": {
                mode: {"eta1": rng.random(), "eta1_low": 0.0, "eta1_high": 1.0, "n": 38, "autonomy": 0.5}
                for mode in MODES
            },
            "calibration": {
                "autonomy_target": 0.8,
                "feasible": True,
                "certified": 12,
                "candidates": 729,
                "guarantee": "With probability ≥ 0.95, each of the 12 certified candidates ...",
                "delta1": 0.9,
                "delta2": 0.8,
                "tau": 0.45,
                "replayed": {"autonomy_low": 0.82, "eta1_unknown": 0.6},
                "uncaught_variants": [
                    {
                        "condition": "white_van",
                        "eta1_off": 0.4,
                        "min_eta2_median": 0.97,
                        "max_mutual_information_median": 0.1,
                    }
                ]
                if m == "vi"
                else [],
            },
        }
        for m in METHODS
    }
    (root / "metrics/avoid.json").write_text(json.dumps(avoided))
    (root / "plots/safety/summary").mkdir(parents=True)
    (root / "plots/safety/summary/hexbin_roundabout_noise0.0.png").write_bytes(png)  # the noise-0.05 one is missing
    return summary, evaluated, avoided


def test_report_tables_hold_the_metrics_files_numbers(stage_config, tmp_path):
    summary, evaluated, avoided = write_run(tmp_path)
    result = run_report(stage_config("report"))
    text = (tmp_path / "reports/report.md").read_text()
    rows = markdown_rows(text, "method | location | weather")
    assert len(rows) == len(METHODS) * len(LOCATIONS) * len(WEATHERS) * len(NOISES)
    for row in rows:
        cell = summary[row["method"]][row["location"]][row["weather"]][f"noise{float(row['noise'])}"]
        assert row["η̂1"] == fmt(cell["eta1"]) and row["corridor use"] == fmt(cell["max_corridor_use"], 2)
        assert row["interval"] == f"[{fmt(cell['eta1_low'])}, {fmt(cell['eta1_high'])}]" and row["n"] == "19"
    pooled_rows = {
        (r["method"], r["location"], r["noise"]): r for r in markdown_rows(text, "method | location | noise")
    }
    cells = [summary["vi"]["roundabout"][w]["noise0.0"] for w in WEATHERS]
    mean = np.mean([c["eta1"] for c in cells])  # the uniform mixture of the weather cells
    assert pooled_rows[("vi", "roundabout", "0")]["η̂1 all weathers"] == fmt(mean)
    fidelity = {r["claim"]: r for r in markdown_rows(text, "claim")}
    assert fidelity["offline, vi, all weathers"]["paper"] == "0.91 ± 0.05"
    assert fidelity["offline, vi, all weathers"]["ours [interval]"].startswith(fmt(mean, 2))
    vi_unknown_on = avoided["vi"]["unknown"]["on"]
    assert fidelity["avoid, vi, unknown conditions, warnings on"]["ours [interval]"] == (
        f"{fmt(vi_unknown_on['eta1'], 2)} [{fmt(0.0, 2)}, {fmt(1.0, 2)}]"
    )
    assert fidelity["avoid, vi, unknown conditions, warnings on"]["overlap"] == "yes"  # [0, 1] holds 0.90
    training = {(r["experiment"], r["method"]): r for r in markdown_rows(text, "experiment | method")}
    assert training[("avoid", "vi")]["val accuracy"] == fmt(
        json.loads((tmp_path / "metrics/avoid/train/vi.json").read_text())["val_accuracy"]
    )
    assert training[("offline", "mcd")]["diagnostics"] == "mcd diagnostics"
    agreement = {r["method"]: r for r in markdown_rows(text, "method | mean TV to HMC")}
    mcd_cells = [evaluated["mcd"][w][f"noise{x}"] for w in WEATHERS for x in NOISES]
    assert agreement["mcd"]["mean TV to HMC"] == fmt(sum(c["hmc_tv_distance"] for c in mcd_cells) / 4)
    assert agreement["mcd"]["worst condition TV"] == fmt(max(c["hmc_tv_distance"] for c in mcd_cells))
    assert agreement["vi"]["MI Spearman ρ"] == "–"
    held_out = markdown_rows(text, "method | weather | noise | frames")
    assert len(held_out) == len(METHODS) * len(WEATHERS) * len(NOISES)
    for row in held_out:
        cell = evaluated[row["method"]][row["weather"]][f"noise{float(row['noise'])}"]
        assert (row["accuracy"], row["ECE"], row["mean MI"], row["AUROC MI"], row["AUROC 1 − η2"]) == (
            fmt(cell["accuracy"]),
            fmt(cell["ece"]),
            fmt(cell["mean_mutual_information"]),
            fmt(cell["auroc_mi"]),
            "–",
        )
    avoid_rows = markdown_rows(text, "method | condition")
    assert len(avoid_rows) == len(METHODS) * (3 + 1) * len(MODES)
    for row in avoid_rows:
        if "mixture" not in row["condition"]:
            cell = avoided[row["method"]]["cells"][row["condition"]][row["warnings"]]
            assert (row["η̂1"], row["autonomy"], row["median hand-over distance (m)"]) == (
                fmt(cell["eta1"]),
                fmt(cell["autonomy"], 2),
                "12.5",
            )
    assert "**vi, white_van**: η̂1 0.40 without warnings and no threshold" in text
    assert "| profile | `tiny` |" in text
    assert "Figure missing: `plots/safety/summary/hexbin_roundabout_noise0.05.png`" in text

    headline = json.loads((tmp_path / "metrics/summary.json").read_text())
    assert headline["offline_safety"]["vi"]["eta1_pooled"] == pytest.approx(
        np.mean([summary["vi"][loc][w][f"noise{x}"]["eta1"] for loc in LOCATIONS for w in WEATHERS for x in NOISES])
    )
    assert headline["avoid"]["mcd"]["unknown_on_eta1"] == avoided["mcd"]["unknown"]["on"]["eta1"]
    assert (
        headline["val_accuracy"]["avoid"]["vi"]
        == json.loads((tmp_path / "metrics/avoid/train/vi.json").read_text())["val_accuracy"]
    )

    html = (tmp_path / "reports/report.html").read_text()
    figures = len(EXPERIMENTS) * len(METHODS) + 1  # learning curves and one hexbin; agreement_hmc.png is missing
    assert result["figures"] == figures and html.count('src="data:image/png;base64,') == figures
    assert not re.search(r'src="(?!data:)', html)  # self-contained: no file links left


def test_missing_metrics_file_names_it(stage_config, tmp_path):
    write_run(tmp_path)
    (tmp_path / "metrics/safety.json").unlink()
    with pytest.raises(FileNotFoundError, match="metrics/safety.json is missing"):
        run_report(stage_config("report"))
    assert not (tmp_path / "reports").exists()
