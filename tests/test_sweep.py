"""A parallel Hydra multirun starting from no MLflow store logs every job (the SQLite creation race)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from uqdrive.pipeline.collect import run_collect
from uqdrive.tracking import store_uris

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_joblib_multirun_of_4_jobs_on_2_workers_logs_4_runs(stage_config, tmp_path):
    raw = tmp_path / "raw"
    run_collect(stage_config("collect", "scenario=straight", "collect.episodes=1", "collect.workers=1",
                             f"paths.raw={raw}", f"paths.root={tmp_path / 'collect-root'}"))
    project = tmp_path / "sweep-root"
    project.mkdir()
    result = subprocess.run(
        [sys.executable, str(ROOT / "stages/preprocess.py"), "-m", "profile=tiny", "progress=false",
         f"paths.root={project}", f"paths.raw={raw}", "scenarios=[straight]", "preprocess.split_seed=0,1,2,3",
         "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path / 'multirun'}"],
        cwd=ROOT, capture_output=True, text=True, timeout=600, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert result.returncode == 0, result.stderr[-3000:]
    client = MlflowClient(store_uris(project)[0])
    runs = client.search_runs([client.get_experiment_by_name("preprocess").experiment_id])
    assert sorted(r.data.params["preprocess.split_seed"] for r in runs) == ["0", "1", "2", "3"]
