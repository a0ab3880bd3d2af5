"""The collect and preprocess stages on the tiny profile, called as DVC would call them (minus the shell)."""

import json
import shutil

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import compose_stage
from mlflow.tracking import MlflowClient

from uqdrive.data.binning import SteeringBins
from uqdrive.data.tables import PROCESSED_SCHEMA, RAW_SCHEMA, images_to_array
from uqdrive.pipeline.collect_stage import run_collect
from uqdrive.pipeline.preprocess_stage import run_preprocess
from uqdrive.records import as_dict
from uqdrive.tracking import store_uris


@pytest.fixture(scope="module")
def collected_once(tmp_path_factory):
    root = tmp_path_factory.mktemp("collected")
    for scenario in ("straight", "roundabout"):
        run_collect(compose_stage(root, "collect", f"scenario={scenario}", "collect.workers=1"))
    return root


@pytest.fixture
def collected(collected_once, tmp_path):
    """A copy of the module's collected frames (and their runs): each test writes its outputs beside its own."""
    shutil.copytree(collected_once, tmp_path, dirs_exist_ok=True)
    return tmp_path


def test_collect_writes_one_row_per_frame_with_the_autopilot_label(collected):
    table = pq.read_table(collected / "data/raw/straight.parquet")
    assert table.schema.equals(RAW_SCHEMA)
    metrics = json.loads((collected / "metrics/collect/straight.json").read_text())
    assert metrics["frames"] == table.num_rows > 100
    assert metrics["episodes"] == 2 and metrics["route_complete_fraction"] == 1.0
    steps = table.column("step").to_numpy()
    episodes = table.column("episode").to_numpy()
    assert set(episodes) == {0, 1} and np.all(np.diff(steps[episodes == 0]) == 1)
    assert set(table.column("seed").to_pylist()) == {1000, 1001}
    assert np.all(np.abs(table.column("steering").to_numpy()) <= 1.0)
    assert (collected / "plots/collect/straight_mosaic.png").stat().st_size > 1000


def test_collect_and_preprocess_log_config_and_metrics_to_mlflow(collected, stage_config):
    run_preprocess(stage_config("preprocess", "experiment=joint", "experiment.scenarios=[straight,roundabout]"))
    client = MlflowClient(store_uris(collected)[0])
    for stage, runs_expected in (("collect", 2), ("preprocess", 1)):
        experiment = client.get_experiment_by_name(f"uqdrive/{stage}")
        runs = client.search_runs([experiment.experiment_id])
        assert len(runs) == runs_expected
        assert runs[0].data.params["profile"] == "tiny"
    collect_runs = client.search_runs([client.get_experiment_by_name("uqdrive/collect").experiment_id])
    assert {r.data.params["location"] for r in collect_runs} == {"straight", "roundabout"}
    assert all(r.data.metrics["frames"] > 0 for r in collect_runs)


def test_preprocess_outputs_frames_labels_and_histogram(collected, stage_config):
    metrics = run_preprocess(
        stage_config("preprocess", "experiment=joint", "experiment.scenarios=[straight,roundabout]")
    )
    train = pq.read_table(collected / "data/processed/joint/train.parquet")
    val = pq.read_table(collected / "data/processed/joint/val.parquet")
    assert train.schema.equals(PROCESSED_SCHEMA)
    assert metrics.train_frames == train.num_rows and metrics.val_frames == val.num_rows
    raw_rows = sum(pq.read_table(collected / f"data/raw/{s}.parquet").num_rows for s in ("straight", "roundabout"))
    assert train.num_rows + val.num_rows == raw_rows
    keys = lambda t: set(zip(t.column("scenario").to_pylist(), t.column("episode").to_pylist()))  # noqa: E731
    assert not keys(train) & keys(val)
    frames = images_to_array(train.column("image"))
    assert frames.shape[1:] == (48, 64) and frames.std() > 10  # a picture, not a blank
    np.testing.assert_array_equal(
        train.column("label").to_numpy(), SteeringBins().to_class(train.column("steering").to_numpy())
    )
    histogram = (collected / "plots/joint/class_histogram.csv").read_text().splitlines()
    assert histogram[0] == "class,steering,split,frames" and len(histogram) == 1 + 2 * 21
    assert json.loads((collected / "metrics/joint/preprocess.json").read_text()) == as_dict(metrics)
    assert metrics.clipped_label_fraction == 0.0  # the joint class set spans every tenth


def test_an_experiment_keeps_only_its_class_set_and_reports_what_it_clips(collected, stage_config):
    metrics = run_preprocess(
        stage_config(
            "preprocess",
            "experiment=offline",
            "experiment.scenarios=[roundabout]",
            "experiment.bins.low=-0.2",
            "experiment.bins.high=0.2",
        )
    )
    train = pq.read_table(collected / "data/processed/offline/train.parquet")
    labels, steering = train.column("label").to_numpy(), train.column("steering").to_numpy()
    assert metrics.num_classes == 5 and labels.min() >= 0 and labels.max() <= 4
    np.testing.assert_array_equal(labels, SteeringBins(low=-0.2, high=0.2).to_class(steering))
    raw = pq.read_table(collected / "data/raw/roundabout.parquet").column("steering").to_numpy()
    assert metrics.clipped_label_fraction == pytest.approx(np.mean((raw < -0.25) | (raw >= 0.25)))


def test_bad_values_fail_before_any_work(stage_config, tmp_path):
    with pytest.raises(ValueError, match="collect.episodes=0"):
        run_collect(stage_config("collect", "collect.episodes=0"))
    with pytest.raises(ValueError, match=r"noise=-0.1"):
        run_collect(stage_config("collect", "noise=-0.1"))
    with pytest.raises(ValueError, match="scenario.kind='loop'"):
        run_collect(stage_config("collect", "scenario.kind=loop"))
    with pytest.raises(ValueError, match=r"collect.name='\.\./x': string should match pattern"):
        run_collect(stage_config("collect", "collect.name=../x"))
    with pytest.raises(FileNotFoundError, match="dvc repro"):
        run_preprocess(stage_config("preprocess", "experiment.scenarios=[straight]"))
    assert not (tmp_path / "data").exists()


def test_corrupt_raw_file_fails_naming_it_and_writes_nothing(stage_config, tmp_path):
    raw = tmp_path / "data/raw/straight.parquet"
    raw.parent.mkdir(parents=True)
    raw.write_bytes(b"PAR1 half of a file")
    with pytest.raises(ValueError, match=f"{raw} is not a readable parquet file"):
        run_preprocess(stage_config("preprocess", "experiment.scenarios=[straight]"))
    assert not (tmp_path / "data/processed").exists() and not (tmp_path / "metrics").exists()


@pytest.mark.slow
def test_worker_count_does_not_change_the_data(stage_config, tmp_path):
    tables = []
    for workers in (1, 2):
        run_collect(
            stage_config(
                "collect", "scenario=obstacle", f"collect.workers={workers}", f"paths.raw={tmp_path}/w{workers}"
            )
        )
        tables.append(pq.read_table(tmp_path / f"w{workers}/obstacle.parquet"))
    assert tables[0].num_rows > 0 and tables[0].equals(tables[1])
