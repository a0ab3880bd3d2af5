"""`uqdrive bound` and `uqdrive bench estimators` end to end."""

from __future__ import annotations

import re

import pytest

from uqdrive.cli import main


def test_bound_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bound", "--theta", "0.05", "--gamma", "0.05"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"chernoff .*\s738\s+planned\s+yes", out)
    assert re.search(r"clopper_pearson .*\s404\s+planned\s+yes", out)
    assert re.search(r"massart, a priori min\(eta,1-eta\) <= 0.1\s+305", out)
    assert re.search(r"sequential \(calibrated Clopper-Pearson\), a look every 1\s+402\s+worst case\s+yes", out)
    assert "expected samples 401 at eta=0.5, 197 at eta=0.9, 84 at eta=0.99, 72 at eta=1" in out
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
    assert main(["bench", "estimators"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    m = re.fullmatch(r"RESULT estimators saving_at_0\.99=([\d.]+) worst_ratio=([\d.]+) worst_vs_cp=([\d.]+)", last)
    assert m, last
    assert float(m[1]) >= 7.5 and float(m[2]) <= 0.6 and float(m[3]) <= 1.12
