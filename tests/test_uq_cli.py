"""`uqdrive bound`, `uqdrive bench estimators` and `uqdrive bench threshold` end to end."""

from __future__ import annotations

import re

import pytest

from uqdrive.tools.cli import main


def test_bound_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bound", "--theta", "0.05", "--gamma", "0.05"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"chernoff .*\s738\s+planned\s+yes", out)
    assert re.search(r"clopper_pearson .*\s404\s+planned\s+yes", out)
    assert re.search(r"massart, a priori min\(eta,1-eta\) <= 0.1\s+305", out)
    assert re.search(r"sequential \(calibrated fit and ball rules\), a look every 1\s+402\s+worst case\s+yes", out)
    expected = "401.4 at eta=0.5, 174.3 at eta=0.9, 93.7 at eta=0.95, 44.7 at eta=0.99, 37.0 at eta=1"
    assert f"expected samples {expected}" in out
    assert re.search(r"sprt .*no \(decision only\)", out)


def test_bound_with_a_wide_theta_still_plans_every_guaranteed_scheme(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bound", "--theta", "0.3", "--gamma", "0.05"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"chernoff .*\s21\s+planned\s+yes", out)
    assert re.search(r"sprt eta >= 0.7 \+- 0.3 \(cap\)\s+n/a", out)


def test_bound_rejects_bad_theta(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bound", "--theta", "1.5"]) == 2
    assert "theta must be in (0, 1), got 1.5" in capsys.readouterr().err
    assert main(["bound", "--look-size", "0"]) == 2
    assert "look_size must be an integer >= 1 (samples between looks), got 0" in capsys.readouterr().err


def test_bench_estimators_meets_its_targets(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "estimators", "--runs", "200", "--split", "2"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    number = r"([\d.]+)"
    m = re.fullmatch(
        rf"RESULT estimators saving_at_0\.99={number} worst_vs_cp={number} en_at_0={number} en_at_1={number} "
        rf"calibrate_s={number} calibrate_cpu_s={number} calibrate_vs_fit_only={number}",
        last,
    )
    assert m, last
    assert float(m[1]) >= 14.7 and float(m[2]) <= 1.12 and float(m[3]) <= 42 and float(m[4]) <= 42


def test_bench_threshold_reports_the_draws_at_eta_1(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "threshold", "--deltas", "0.7", "--budget", "100"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    number = r"([\d.]+)"
    m = re.fullmatch(
        rf"RESULT threshold en_at_1={number} saving_at_1={number} en_at_0\.9={number} worst_en={number} "
        rf"worst_vs_fixed={number} build_s={number}",
        last,
    )
    assert m, last
    assert float(m[1]) == 12.0 and float(m[5]) < 0.3
