"""`uqdrive bench sim|posterior` run end to end on small sizes and end with their RESULT line.

Only the output contract is tested here; the speed targets are measured by running the
benchmarks themselves (README), never asserted in timed tests.
"""

from __future__ import annotations

import re

import pytest

from uqdrive.cli import main


@pytest.mark.parametrize(("argv", "pattern"), [
    (["sim", "--steps", "30", "--repeats", "1"], r"RESULT sim step_over_render=[\d.]+"),
    (["posterior", "--samples", "50", "--repeats", "2"], r"RESULT posterior worst_ms=[\d.]+ min_speedup=[\d.]+"),
])
def test_benchmark_prints_its_result_line(capsys: pytest.CaptureFixture[str], argv: list[str], pattern: str) -> None:
    assert main(["bench", *argv]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert re.fullmatch(pattern, last), last


def test_unknown_benchmark_is_named_with_the_choices(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "warp"]) == 2
    assert "unknown benchmark 'warp'; choose one of" in capsys.readouterr().err
