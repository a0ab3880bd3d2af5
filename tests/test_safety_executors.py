"""Same seeds ⇒ same η̂1 and the same per-rollout outcomes, whatever the backend and worker count."""

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import ray_kit
from conftest import ALL_TENTHS, CONF, cell_result

from uqdrive.data.binning import SteeringBins
from uqdrive.parallel import RAY_MISSING
from uqdrive.policy.recipes import ControllerSpec
from uqdrive.safety.cells import EstimatorSettings
from uqdrive.safety.executors import RolloutJob, make_executor
from uqdrive.safety.runner import CellRunner
from uqdrive.schema import ConfigError
from uqdrive.sim import ScenarioConfig, WeatherConfig
from uqdrive.sim.condition import Condition
from uqdrive.stage import stage_main

ROOT = Path(__file__).resolve().parents[1]

SETTINGS = EstimatorSettings("chernoff", 0.6, 0.05, 500)  # 6 rollouts, seeds 500 … 505


def job(model_path) -> RolloutJob:
    """The BNN controller in rain with sensor noise: every seeded source of randomness is in play."""
    spec = ControllerSpec(6.0, str(model_path), "vi", SteeringBins(), samples=20, eps=0.1)
    roundabout = ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout.yaml")
    rain = WeatherConfig.from_yaml(CONF / "weather" / "rain.yaml")
    return RolloutJob(spec, Condition(roundabout, rain, 0.05), base_seed=SETTINGS.base_seed)


def outcomes(backend: str, workers: int, model_path) -> tuple[float, list]:
    with tempfile.TemporaryDirectory() as log, CellRunner(backend, workers, progress=False) as runner:
        run = runner.estimate("cell", job(model_path), SETTINGS, "key", Path(log) / "cell.jsonl")
    return run.outcome.value, run.results


def assert_same(a: tuple[float, list], b: tuple[float, list]) -> None:
    assert a[0] == b[0]
    assert [r.summary() for r in a[1]] == [r.summary() for r in b[1]]
    for ra, rb in zip(a[1], b[1]):
        assert np.array_equal(ra.x, rb.x) and np.array_equal(ra.y, rb.y)


@pytest.fixture(scope="module")
def one_worker(random_models):
    return outcomes("process", 1, random_models["vi"])


@pytest.mark.slow
def test_one_and_two_worker_processes_agree(one_worker, random_models):
    assert [r.seed for r in one_worker[1]] == list(range(500, 506))
    assert len({r.steps for r in one_worker[1]} | {len(r.x) for r in one_worker[1]}) > 1  # paths differ by seed
    assert_same(one_worker, outcomes("process", 2, random_models["vi"]))


@pytest.mark.slow
def test_ray_backend_agrees_with_the_process_pool(one_worker, random_models):
    pytest.importorskip("ray")
    assert_same(one_worker, outcomes("ray", 2, random_models["vi"]))


def test_unknown_backend_and_bad_worker_count_fail_before_any_rollout(random_models):
    with pytest.raises(
        ValueError, match=r"executor.name='dask' is not a known backend; choose one of \['process', 'ray'\]"
    ):
        make_executor("dask", job(random_models["vi"]), 2)
    with pytest.raises(ValueError, match="workers=0 must be >= 1"):
        make_executor("process", job(random_models["vi"]), 0)


def test_executor_ray_without_ray_installed_is_one_line_naming_what_to_install(random_models, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError, as where it is not installed
    with pytest.raises(SystemExit) as stopped:
        stage_main(lambda: make_executor("ray", job(random_models["vi"]), 1))()
    assert stopped.value.code == 2
    assert capsys.readouterr().err == f"error: {RAY_MISSING}\n"  # no traceback
    assert "pip install 'uqdrive[ray]'" in RAY_MISSING and "executor.name=ray" in RAY_MISSING


def test_executor_ray_at_an_address_nobody_listens_at_is_one_line_naming_it(random_models):
    pytest.importorskip("ray")
    address = f"127.0.0.1:{ray_kit.free_port()}"
    with pytest.raises(ConfigError, match=rf"^executor.address='{address}': no Ray cluster answers there \(") as err:
        make_executor("ray", job(random_models["vi"]), 1, address=address)
    assert "\n" not in str(err.value) and "ray start --head" in str(err.value)
    with pytest.raises(ConfigError, match=r"^executor.address='ray://nowhere': no Ray cluster answers there"):
        make_executor("ray", job(random_models["vi"]), 1, address="ray://nowhere")


@pytest.fixture
def ray_cluster():
    """A real one-node Ray cluster on loopback, started as a user would (`ray_kit.ray_cluster`), always stopped."""
    pytest.importorskip("ray")
    with ray_kit.ray_cluster() as cluster:
        yield cluster


@pytest.mark.slow
def test_the_readme_ray_path_on_a_ray_cluster_agrees_with_the_process_backend(
    ray_cluster, stage_config, random_models, tmp_path
):
    """`python stages/safety.py executor=ray executor.address=auto` joins the cluster (RAY_ADDRESS) and gives the
    same cell, rollout by rollout, as the process pool."""
    cell = [
        "profile=tiny",
        "progress=false",
        "model=vi",
        "weather=rain",
        "noise=0.05",
        f"safety.model_path={random_models['vi'].parent}/${{model.name}}.pt",
        *ALL_TENTHS,
    ]
    env, cluster_dir = ray_cluster
    on_ray = tmp_path / "ray"
    on_ray.mkdir()
    ray_kit.run_stage(env, on_ray, "safety.py", *cell, "executor=ray", "executor.address=auto")
    name = "vi-seed0-roundabout-rain-noise0.05"
    from uqdrive.pipeline.safety_stage import run_safety
    from uqdrive.records import as_dict

    local = as_dict(run_safety(stage_config("safety", *cell[2:], "executor=process", "executor.workers=2")).cell)
    remote = json.loads((on_ray / f"metrics/safety/{name}.json").read_text())
    assert cell_result(remote) == cell_result(local)
    assert (on_ray / f"plots/safety/cells/{name}.csv").read_text() == (
        tmp_path / f"plots/safety/cells/{name}.csv"
    ).read_text()
    assert list(cluster_dir.glob("session_*/logs/python-core-driver-*"))  # the stage was a driver of this cluster
