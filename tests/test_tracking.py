import mlflow
from mlflow.tracking import MlflowClient
from omegaconf import OmegaConf

from uqdrive.tracking import ensure_experiment, flatten, stage_run, store_uris


def test_flatten_nested_config_to_dotted_params():
    cfg = OmegaConf.create({"a": {"b": 1, "c": {"d": "x"}}, "lst": [1, 2], "ref": "${a.b}"})
    assert flatten(cfg) == {"a.b": "1", "a.c.d": "x", "lst": "[1, 2]", "ref": "1"}


def test_stage_run_creates_store_at_root_and_logs_the_config(tmp_path):
    cfg = OmegaConf.create({"collect": {"episodes": 3}, "scenario": {"name": "obstacle"}})
    with stage_run(tmp_path, "collect", cfg, run_name="obstacle") as run:
        mlflow.log_metric("frames", 42)
        mlflow.log_text("hello", "note.txt")
    tracking_uri, artifact_root = store_uris(tmp_path)
    assert (tmp_path / "mlflow.db").exists()
    logged = MlflowClient(tracking_uri).get_run(run.info.run_id)
    assert logged.data.params == {"collect.episodes": "3", "scenario.name": "obstacle"}
    assert logged.data.metrics == {"frames": 42.0}
    assert logged.info.artifact_uri.startswith(artifact_root)
    assert (tmp_path / "mlartifacts").is_dir()


def test_one_experiment_per_stage_is_reused(tmp_path):
    first = ensure_experiment(tmp_path, "preprocess")
    assert ensure_experiment(tmp_path, "preprocess") == first
    assert ensure_experiment(tmp_path, "collect") != first
