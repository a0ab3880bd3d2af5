"""What a stage run shows and leaves, as a user runs it from the project folder: its progress bar with no pybullet
banner inside it (worker processes import pybullet too), and no empty Hydra job log under outputs/."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_a_stage_with_worker_processes_prints_its_bar_without_the_pybullet_banner_and_leaves_no_empty_log(tmp_path):
    shutil.copy(ROOT / "params.yaml", tmp_path / "params.yaml")
    result = subprocess.run(
        [sys.executable, str(ROOT / "stages/collect.py"), "profile=tiny", "collect.episodes=2", "collect.workers=2"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "collect straight: 100%" in result.stderr  # the bar, to its end
    assert "pybullet build time" not in result.stderr + result.stdout
    logs = list((tmp_path / "outputs").rglob("*.log"))
    assert not [log for log in logs if log.stat().st_size == 0], logs
    assert list((tmp_path / "outputs").rglob("metrics/collect/straight.json"))
