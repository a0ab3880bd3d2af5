"""A parallel Hydra multirun of the safety stage from no MLflow store: 4 jobs on 2 workers → 4 child runs
under one parent run for the sweep."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ALL_TENTHS
from mlflow.tracking import MlflowClient

from uqdrive.tracking import store_uris

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_joblib_multirun_of_4_cells_on_2_workers_logs_4_child_runs(random_models, tmp_path):
    """Run from the project folder with the default paths.root (${hydra:runtime.cwd}), as a user would."""
    project = tmp_path / "project"
    project.mkdir()
    result = subprocess.run(
        [
            sys.executable,
            str(ROOT / "stages/safety.py"),
            "-m",
            "profile=tiny",
            "progress=false",
            f"safety.model_path={random_models['mcd'].parent}/${{model.name}}.pt",
            *ALL_TENTHS,
            "model=mcd,vi",
            "weather=clear_noon,rain",
            "hydra/launcher=joblib",
            "hydra.launcher.n_jobs=2",
            f"hydra.sweep.dir={tmp_path / 'multirun'}",
        ],
        cwd=project,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Callback" not in result.stderr, result.stderr[-3000:]  # the parent run was created (paths.root = cwd)
    logs = list((tmp_path / "multirun").rglob("*.log"))
    assert not [log for log in logs if log.stat().st_size == 0], logs  # Hydra's job log only where a job logged
    client = MlflowClient(store_uris(project)[0])
    runs = client.search_runs([client.get_experiment_by_name("uqdrive/safety").experiment_id])
    (parent,) = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
    assert parent.info.run_name == "adhoc · sweep safety" and parent.info.status == "FINISHED"
    assert sorted((r.data.params["method"], r.data.params["weather"]) for r in children) == [
        ("mcd", "clear_noon"),
        ("mcd", "rain"),
        ("vi", "clear_noon"),
        ("vi", "rain"),
    ]
    assert len(runs) == 5
    assert len(list((tmp_path / "multirun/metrics/safety").glob("*.json"))) == 4  # the sweep's own folder
    assert not (project / "metrics").exists()
