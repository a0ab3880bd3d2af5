"""`uqdrive bench sim|posterior|rollout` run end to end on small sizes and end with their RESULT line.

Only the output contract is tested here; the speed targets are measured by running the
benchmarks themselves (README), never asserted in timed tests.
"""

from __future__ import annotations

import re

import pytest

from uqdrive.cli import main


@pytest.mark.parametrize(
    ("argv", "pattern"),
    [
        (["sim", "--steps", "30", "--repeats", "1"], r"RESULT sim step_over_render=[\d.]+"),
        (["posterior", "--samples", "50", "--repeats", "2"], r"RESULT posterior worst_ms=[\d.]+ min_speedup=[\d.]+"),
    ],
)
def test_benchmark_prints_its_result_line(capsys: pytest.CaptureFixture[str], argv: list[str], pattern: str) -> None:
    assert main(["bench", *argv]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert re.fullmatch(pattern, last), last


@pytest.mark.slow
def test_rollout_benchmark_prints_its_result_line(capsys: pytest.CaptureFixture[str]) -> None:
    """Spawns two worker processes (torch and pybullet start-up in each): tens of seconds."""
    assert main(["bench", "rollout", "--samples", "20", "--steps", "15", "--repeats", "1", "--chunks", "3"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert any(line.startswith("closed loop, 160x120:") for line in out)
    assert re.fullmatch(r"RESULT rollout overhead=[\d.]+ speedup2=[\d.]+ render_speedup=[\d.]+", out[-1]), out[-1]


def test_unknown_benchmark_is_named_with_the_choices(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "warp"]) == 2
    assert "unknown benchmark 'warp'; choose one of" in capsys.readouterr().err
