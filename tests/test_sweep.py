"""A parallel Hydra multirun starting from no MLflow store logs every job (the SQLite creation race)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hydra.conf import HydraConf
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from mlflow.tracking import MlflowClient
from omegaconf import OmegaConf

from uqdrive.pipeline.collect_stage import run_collect
from uqdrive.schema import config_error
from uqdrive.tracking import store_lock, store_uris

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_joblib_multirun_of_4_jobs_on_2_workers_logs_4_runs(stage_config, tmp_path):
    raw = tmp_path / "raw"
    run_collect(
        stage_config(
            "collect",
            "scenario=straight",
            "collect.episodes=1",
            "collect.workers=1",
            f"paths.raw={raw}",
            f"paths.root={tmp_path / 'collect-root'}",
        )
    )
    project = tmp_path / "sweep-root"
    project.mkdir()
    result = subprocess.run(
        [
            sys.executable,
            str(ROOT / "stages/preprocess.py"),
            "-m",
            "profile=tiny",
            "progress=false",
            f"paths.root={project}",
            f"paths.raw={raw}",
            "experiment=joint",
            "experiment.scenarios=[straight]",
            "preprocess.split_seed=0,1,2,3",
            "hydra/launcher=joblib",
            "hydra.launcher.n_jobs=2",
            f"hydra.sweep.dir={tmp_path / 'multirun'}",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    client = MlflowClient(store_uris(project)[0])
    runs = client.search_runs([client.get_experiment_by_name("uqdrive/preprocess").experiment_id])
    assert sorted(r.data.params["preprocess.split_seed"] for r in runs) == ["0", "1", "2", "3"]


WAIT_S = 600  # each wait is bounded; a 2-core machine running other suites beside this one needs minutes


def _sweep(project: Path, *overrides: str) -> subprocess.Popen:
    """The sweep as a child process; its output goes to files in `project` (a pipe nobody reads while we
    wait could fill up and stall it)."""
    return subprocess.Popen(
        [
            sys.executable,
            str(ROOT / "stages/collect.py"),
            "-m",
            "profile=tiny",
            "progress=false",
            "scenario=straight",
            "collect.workers=1",
            "+tracking.parent_run=true",
            *overrides,
        ],
        cwd=project,
        stdout=(project / "stdout.txt").open("w"),
        stderr=(project / "stderr.txt").open("w"),
        env={**os.environ, "PYTHONPATH": str(ROOT / "src"), "PYTHONWARNINGS": "ignore"},
    )


def _finish(sweep: subprocess.Popen, project: Path) -> str:
    """Wait (bounded) for the sweep to end; its stderr."""
    try:
        sweep.wait(timeout=WAIT_S)
    finally:
        sweep.kill()
    return (project / "stderr.txt").read_text()


def _runs(project: Path) -> list:
    with store_lock(project):  # the sweep may be creating the store right now
        client = MlflowClient(store_uris(project)[0])
    experiment = client.get_experiment_by_name("uqdrive/collect")
    return client.search_runs([experiment.experiment_id]) if experiment else []


@pytest.mark.slow
def test_an_interrupted_or_failed_sweep_leaves_no_run_running(tmp_path):
    interrupted = tmp_path / "interrupted"
    interrupted.mkdir()
    sweep = _sweep(interrupted, "collect.episodes=500", "collect.base_seed=1,2")
    deadline = time.monotonic() + WAIT_S
    while not (interrupted / "mlflow.db").exists() or not _runs(interrupted):  # the parent run is open
        if time.monotonic() > deadline or sweep.poll() is not None:
            sweep.kill()
            pytest.fail(f"no parent run: {(interrupted / 'stderr.txt').read_text()[-3000:]}")
        time.sleep(0.5)
    sweep.send_signal(signal.SIGINT)  # Ctrl-C during the first job
    _finish(sweep, interrupted)
    (parent,) = _runs(interrupted)
    assert parent.info.status == "KILLED" and sweep.returncode != 0

    failed = tmp_path / "failed"
    failed.mkdir()
    sweep = _sweep(failed, "collect.episodes=1", "noise=0,-1")  # the second job has a bad value
    err = _finish(sweep, failed)
    assert sweep.returncode == 2 and "error: noise=-1: input should be greater than or equal to 0" in err
    statuses = sorted((r.info.status, "mlflow.parentRunId" in r.data.tags) for r in _runs(failed))
    assert statuses == [("FAILED", False), ("FINISHED", True)]  # the parent, and the first job's run
    # the sweep wrote under its own folder, not into the project's pipeline outputs
    assert not any((failed / name).exists() for name in ("data", "metrics", "plots"))
    assert len(list(failed.glob("multirun/*/*/metrics/collect/straight.json"))) == 1


@pytest.mark.parametrize("noise", ["0", "0.0", "0.00"])
def test_one_noise_level_is_one_cell(stage_config, noise):
    safety = stage_config("safety", f"noise={noise}")
    heldout = stage_config("heldout", f"noise={noise}")
    assert safety.safety.cell == "mcd-seed0-roundabout-clear_noon-noise0.0"  # as DVC names params.yaml's 0.0
    assert Path(heldout.collect.out).name == "roundabout-clear_noon-noise0.0.parquet"


@pytest.fixture
def multirun_mode():
    """Hydra's config as in a multirun job (mode MULTIRUN, a sweep folder)."""
    cfg = OmegaConf.create({"hydra": OmegaConf.structured(HydraConf)})
    cfg.hydra.mode = RunMode.MULTIRUN
    cfg.hydra.sweep.dir = "multirun/2026-01-01/00-00-00"
    HydraConfig.instance().set_config(cfg)
    yield
    HydraConfig.instance().cfg = None


def test_a_multirun_writes_under_its_sweep_folder_unless_asked(stage_config, tmp_path, multirun_mode):
    swept = stage_config("safety")
    sweep = tmp_path / "multirun/2026-01-01/00-00-00"
    assert (swept.safety.out, swept.safety.positions, swept.safety.model_path) == (
        f"{sweep}/metrics/safety/mcd-seed0-roundabout-clear_noon-noise0.0.json",
        f"{sweep}/data/safety/mcd-seed0-roundabout-clear_noon-noise0.0.npz",
        f"{tmp_path}/models/offline/mcd/seed0.pt",
    )
    assert (
        stage_config("safety", "outputs=pipeline").safety.out
        == f"{tmp_path}/metrics/safety/mcd-seed0-roundabout-clear_noon-noise0.0.json"
    )
    with pytest.raises(Exception) as bad:
        _ = stage_config("safety", "outputs=somewhere").safety.out
    assert str(config_error(bad.value)) == "outputs='somewhere' is not known; choose one of ['auto', 'pipeline']"


def test_a_single_run_writes_the_pipeline_outputs(stage_config, tmp_path):
    expected = {
        ("collect", "collect.out"): "data/raw/straight.parquet",
        ("preprocess", "paths.processed"): "data/processed/offline",
        ("train", "paths.models"): "models/offline/mcd",
        ("safety", "safety.out"): "metrics/safety/mcd-seed0-roundabout-clear_noon-noise0.0.json",
        ("avoid", "avoid.out"): "metrics/avoid/mcd-seed0.json",
        ("report", "report.out_dir"): "reports",
    }
    for (stage, key), path in expected.items():
        assert OmegaConf.select(stage_config(stage), key) == f"{tmp_path}/{path}"
