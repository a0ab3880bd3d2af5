import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import mlflow
import pytest
from mlflow.tracking import MlflowClient
from omegaconf import OmegaConf

from uqdrive import tracking
from uqdrive.tracking import JOB_START_ENV, ensure_experiment, flatten, run_params, stage_run, store_uris


def test_flatten_nested_config_to_dotted_params():
    cfg = OmegaConf.create({"a": {"b": 1, "c": {"d": "x"}}, "lst": [1, 2], "ref": "${a.b}"})
    assert flatten(cfg) == {"a.b": "1", "a.c.d": "x", "lst": "[1, 2]", "ref": "1"}


def test_params_are_the_stage_section_and_the_compared_keys_with_project_paths_relative(tmp_path):
    cfg = OmegaConf.create(
        {
            "safety": {"theta": 0.25, "out": f"{tmp_path}/metrics/safety/a.json", "draws": {"theta": 0.05}},
            "avoid": {"theta": 0.05},
            "paths": {"root": str(tmp_path)},
            "model": {"name": "vi"},
            "weather": {"name": "rain", "fog": 0.1},
            "noise": 0.05,
            "scenario": {"name": "roundabout"},
            "profile_name": "tiny",
            "seed": 0,
            "camera": {"width": 160},
        }
    )
    assert run_params(cfg, "safety", tmp_path) == {
        "cell_theta": "0.25",  # compared by: under a name that says whose, once
        "frame_draws.theta": "0.05",  # the per-frame draws' own θ, apart from the cell's
        "safety.out": "metrics/safety/a.json",
        "method": "vi",
        "weather": "rain",
        "noise": "0.05",
        "location": "roundabout",
        "profile": "tiny",
        "replicate": "0",  # the training seed
    }


def test_stage_run_creates_store_at_root_and_starts_when_the_job_started(tmp_path, monkeypatch):
    monkeypatch.setenv(JOB_START_ENV, "1700000000000")
    cfg = OmegaConf.create({"collect": {"episodes": 3}, "scenario": {"name": "obstacle"}})
    with stage_run(tmp_path, "collect", cfg, run_name="obstacle") as run:
        mlflow.log_metrics({"frames": 42, "route_complete_fraction": 0.5})
        mlflow.log_text("hello", "note.txt")
    tracking_uri, artifact_root = store_uris(tmp_path)
    assert (tmp_path / "mlflow.db").exists()
    logged = MlflowClient(tracking_uri).get_run(run.info.run_id)
    assert logged.data.params == {"collect.episodes": "3", "location": "obstacle"}
    assert logged.data.metrics == {"frames": 42.0, "route_complete_fraction": 0.5}
    assert logged.info.start_time == 1700000000000 and logged.info.status == "FINISHED"
    # the key metric, seen without set-up, at fixed precision; no outputs=pipeline: an ad-hoc run
    assert logged.info.run_name == "adhoc · obstacle · complete=0.50"
    assert logged.info.artifact_uri.startswith(artifact_root)
    assert (tmp_path / "mlartifacts").is_dir()


def test_a_store_that_cannot_be_opened_warns_and_the_stage_goes_on(tmp_path, monkeypatch):
    monkeypatch.setattr(tracking, "LOCK_TIMEOUT_S", 0.2)
    result = tmp_path / "result.json"
    result.write_text("{}")
    with tracking.store_lock(tmp_path):  # another process stuck while creating the store
        with pytest.warns(UserWarning, match="MLflow: no run logged for safety adhoc · cell"):
            with stage_run(tmp_path, "safety", OmegaConf.create({}), run_name="cell") as run:
                mlflow.log_metric("eta1", 1.0)
    assert run.info.run_id is None and result.read_text() == "{}"
    assert not (tmp_path / "mlflow.db").exists() and not (tmp_path / "mlruns").exists()


def test_a_failure_while_logging_warns_and_ends_the_run_failed(tmp_path):
    with pytest.warns(UserWarning, match="logging safety adhoc · cell failed"):
        with stage_run(tmp_path, "safety", OmegaConf.create({}), run_name="cell") as run:
            mlflow.log_artifact(str(tmp_path / "no-such-file.png"))
    assert MlflowClient(store_uris(tmp_path)[0]).get_run(run.info.run_id).info.status == "FAILED"


def git_project(root: Path) -> str:
    """A git work tree at ``root`` with one commit; its hash."""

    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(root), *args], check=True, capture_output=True, text=True).stdout

    git("init", "-q")
    (root / "params.yaml").write_text("profile: tiny\n")
    git("add", "params.yaml")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "one")
    return git("rev-parse", "HEAD").strip()


def test_runs_say_their_commit_dvc_experiment_and_whether_the_pipeline_ran_them(tmp_path, monkeypatch):
    commit = git_project(tmp_path)
    monkeypatch.setenv("DVC_EXP_NAME", "rainy-days")
    client = MlflowClient(store_uris(tmp_path)[0])
    for outputs, name in (("pipeline", "rain σ0.1"), ("auto", "rain σ0.1")):
        with stage_run(tmp_path, "safety", OmegaConf.create({"outputs": outputs}), run_name=name) as run:
            mlflow.log_metrics({"eta1": 0.93, "eta1_low": 0.881, "eta1_high": 0.96, "n": 40})
        logged = client.get_run(run.info.run_id)
        assert logged.data.tags["mlflow.source.git.commit"] == commit
        assert f"git commit `{commit}`" in logged.data.tags["mlflow.note.content"]  # shown on the run page
        assert logged.data.tags["uqdrive.dvc_experiment"] == "rainy-days"
        assert logged.data.tags["uqdrive.origin"] == {"pipeline": "pipeline", "auto": "adhoc"}[outputs]
        assert logged.data.metrics["eta1_low"] == 0.881  # short names: the table's columns
        shown = "rain σ0.1 · η1=0.93 [0.88, 0.96]"
        assert logged.info.run_name == {"pipeline": shown, "auto": f"adhoc · {shown}"}[outputs]
    assert [e.name for e in client.search_experiments()] == ["uqdrive/safety"]  # no empty `Default`


def test_the_experiment_prefix_is_the_configs_else_the_environments(tmp_path, monkeypatch):
    monkeypatch.setenv(tracking.PREFIX_ENV, "night-study")
    no_prefix = OmegaConf.create({"tracking": {"experiment_prefix": None}})
    assert tracking.experiment_name("safety", no_prefix) == "night-study/safety"
    assert tracking.experiment_name("safety", {"tracking": {"experiment_prefix": "mine"}}) == "mine/safety"
    monkeypatch.delenv(tracking.PREFIX_ENV)
    assert tracking.experiment_name("avoid", no_prefix) == "uqdrive/avoid"
    with stage_run(tmp_path, "avoid", {"tracking": {"experiment_prefix": "mine"}}) as run:
        pass
    client = MlflowClient(store_uris(tmp_path)[0])
    assert client.get_experiment(client.get_run(run.info.run_id).info.experiment_id).name == "mine/avoid"


def test_every_cell_logs_its_files_under_one_name_so_compare_lines_them_up(tmp_path):
    client = MlflowClient(store_uris(tmp_path)[0])
    for cell in ("mcd-seed0-roundabout-rain-0.1", "vi-seed0-roundabout-rain-0.1"):
        (tmp_path / f"{cell}.png").write_bytes(b"png of " + cell.encode())
        with stage_run(tmp_path, "safety", {}, run_name=cell, tags={"cell": cell}) as run:
            tracking.log_artifact_as(tmp_path / f"{cell}.png", "paths.png")
        assert [a.path for a in client.list_artifacts(run.info.run_id)] == ["paths.png"]
        assert client.get_run(run.info.run_id).data.tags["cell"] == cell
        saved = Path(client.download_artifacts(run.info.run_id, "paths.png", str(tmp_path / run.info.run_id)))
        assert saved.read_bytes() == b"png of " + cell.encode()


def test_artefacts_follow_a_copied_project_not_the_original_folder(tmp_path):
    original, copy = tmp_path / "original", tmp_path / "copy"
    original.mkdir()
    (original / "figure.png").write_bytes(b"original")
    with stage_run(original, "safety", {}, run_name="cell") as run:
        mlflow.log_artifact(str(original / "figure.png"))
    shutil.copytree(original, copy)
    shutil.rmtree(original)
    tracking.follow_project(copy)  # `make ui`, or any stage, opening the copied store
    client = MlflowClient(store_uris(copy)[0])
    logged = client.get_run(run.info.run_id)
    assert logged.info.artifact_uri.startswith(store_uris(copy)[1] + "/")
    assert client.get_experiment(logged.info.experiment_id).artifact_location.startswith(store_uris(copy)[1] + "/")
    saved = client.download_artifacts(run.info.run_id, "figure.png", str(tmp_path))
    assert Path(saved).read_bytes() == b"original"


def test_a_grid_stage_nests_its_cells_under_one_parent_run_per_invocation(tmp_path):
    client = MlflowClient(store_uris(tmp_path)[0])
    with tracking.stage_parent_run(tmp_path, "safety", {}, ["profile=tiny"], name="sweep of 2 cells"):
        children = []
        for cell in ("a", "b"):
            with stage_run(tmp_path, "safety", {}, run_name=cell) as run:
                children.append(run.info.run_id)
    parents = {client.get_run(c).data.tags["mlflow.parentRunId"] for c in children}
    assert len(parents) == 1
    parent = client.get_run(parents.pop())
    assert parent.info.status == "FINISHED" and parent.info.run_name == "adhoc · sweep of 2 cells"
    assert parent.data.tags["uqdrive.overrides"] == "profile=tiny"
    with pytest.raises(RuntimeError), tracking.stage_parent_run(tmp_path, "safety", {}, [], name="failing"):
        raise RuntimeError("a cell failed")
    failed = client.search_runs([parent.info.experiment_id], "attributes.run_name = 'adhoc · failing'")
    assert [r.info.status for r in failed] == ["FAILED"]
    with stage_run(tmp_path, "safety", {}, run_name="alone") as run:
        pass
    assert "mlflow.parentRunId" not in client.get_run(run.info.run_id).data.tags


def test_a_grid_stage_run_as_a_multiruns_job_nests_under_the_multirun_and_hands_its_parent_back(tmp_path, monkeypatch):
    client = MlflowClient(store_uris(tmp_path)[0])
    experiment_id = ensure_experiment(tmp_path, "uqdrive/safety")
    sweep = client.create_run(experiment_id, run_name="sweep safety_sweep").info.run_id
    monkeypatch.setenv(tracking.PARENT_RUN_ENV, f"{experiment_id}:{sweep}")
    with tracking.stage_parent_run(tmp_path, "safety", {}, [], name="sweep of 1 cells"):
        with stage_run(tmp_path, "safety", {}, run_name="cell") as cell:
            pass
    invocation = client.get_run(cell.info.run_id).data.tags["mlflow.parentRunId"]
    assert client.get_run(invocation).data.tags["mlflow.parentRunId"] == sweep
    assert os.environ[tracking.PARENT_RUN_ENV] == f"{experiment_id}:{sweep}"  # for the multirun's next job


def test_one_experiment_per_stage_is_reused(tmp_path):
    first = ensure_experiment(tmp_path, "preprocess")
    assert ensure_experiment(tmp_path, "preprocess") == first
    assert ensure_experiment(tmp_path, "collect") != first


CHILD = """
import sys, time
from pathlib import Path
import mlflow
from omegaconf import OmegaConf
from uqdrive.files import write_json
from uqdrive.tracking import stage_run
name, roots = sys.argv[1], [Path(p) for p in sys.argv[2:]]
for root in roots:  # each attempt a new store: both processes create it at the same moment
    (root / f"ready-{name}").touch()
    while len(list(root.glob("ready-*"))) < 2:
        time.sleep(0.002)
    write_json(root / f"{name}.json", {"eta1": 1.0})
    with stage_run(root, "safety", OmegaConf.create({"safety": {"cell": name}}), run_name=name):
        mlflow.log_metrics({"eta1": 1.0, "eta1_low": 0.9, "eta1_high": 1.0})
"""


@pytest.mark.slow
def test_two_processes_creating_the_store_at_once_both_log(tmp_path):
    """Separate jobs (not one multirun) on a new store: without the lock, MLflow 3.17's migration races
    ('duplicate column name: step', 'Online migration expected to match one row'). Two processes race on five
    new stores in turn (each process imports MLflow once)."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src"), "PYTHONWARNINGS": "default"}
    roots = [tmp_path / f"attempt{attempt}" for attempt in range(5)]
    for root in roots:
        root.mkdir()
    children = [
        subprocess.Popen(
            [sys.executable, "-c", CHILD, name, *map(str, roots)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name in ("a", "b")
    ]
    outputs = [child.communicate(timeout=300) for child in children]
    for child, (_, err) in zip(children, outputs):
        assert child.returncode == 0 and "MLflow:" not in err, err[-3000:]
    for root in roots:
        client = MlflowClient(store_uris(root)[0])
        runs = client.search_runs([client.get_experiment_by_name("uqdrive/safety").experiment_id])
        assert sorted(r.info.run_name for r in runs) == [f"adhoc · {n} · η1=1.00 [0.90, 1.00]" for n in "ab"]
        assert all(r.info.status == "FINISHED" for r in runs)
        assert (root / "a.json").exists() and (root / "b.json").exists()


# "marked" goes to stderr and "ready" is printed inside the swallowing loop: CPython runs signal handlers inside
# a stdout flush too, so a handler printing to stdout while "ready" is being flushed fails as a reentrant call,
# and the KeyboardInterrupt raised there must be swallowed like any other (seen once on a loaded machine).
SWALLOWS_INTERRUPTS = """
import signal, sys, time
from uqdrive.tracking import interrupt_handler
handler = interrupt_handler(signal.getsignal(signal.SIGINT), lambda: print("marked", file=sys.stderr, flush=True), 1.0)
signal.signal(signal.SIGINT, handler)
ready = False
while True:
    try:
        if not ready:
            print("ready", flush=True)
            ready = True
        time.sleep(0.05)
    except BaseException:  # library code with a bare `except:` (around an import, say) eats the KeyboardInterrupt
        pass
"""


def test_an_interrupt_that_library_code_swallows_still_ends_the_process():
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    child = subprocess.Popen(
        [sys.executable, "-c", SWALLOWS_INTERRUPTS], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout.readline() == "ready\n"
        child.send_signal(signal.SIGINT)
        _, err = child.communicate(timeout=120)
    finally:
        child.kill()
    assert "marked" in err.splitlines() and child.returncode == -signal.SIGINT
