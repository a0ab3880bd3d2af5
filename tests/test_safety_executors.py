"""Same seeds ⇒ same η̂1 and the same per-rollout outcomes, whatever the backend and worker count."""

import numpy as np
import pytest

from uqdrive.data.binning import SteeringBins
from uqdrive.safety import EstimatorSettings, PolicySpec, RolloutJob, estimate_safety, make_executor
from uqdrive.sim import ScenarioConfig, WeatherConfig

from conftest import CONF

SETTINGS = EstimatorSettings("chernoff", 0.6, 0.05, 500)  # 6 rollouts, seeds 500 … 505


def job(model_path) -> RolloutJob:
    """The BNN controller in rain with sensor noise: every seeded source of randomness is in play."""
    spec = PolicySpec("bnn", 6.0, str(model_path), "vi", SteeringBins(), samples=20, eps=0.1)
    return RolloutJob(spec, ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout.yaml"),
                      WeatherConfig.from_yaml(CONF / "weather" / "rain.yaml"), 0.05, base_seed=SETTINGS.base_seed)


def outcomes(backend: str, workers: int, model_path) -> tuple[float, list]:
    estimate, results = estimate_safety(make_executor(backend, job(model_path), workers), SETTINGS)
    return estimate.value, results


def assert_same(a: tuple[float, list], b: tuple[float, list]) -> None:
    assert a[0] == b[0]
    assert [r.summary() for r in a[1]] == [r.summary() for r in b[1]]
    for ra, rb in zip(a[1], b[1]):
        assert np.array_equal(ra.x, rb.x) and np.array_equal(ra.y, rb.y)


@pytest.fixture(scope="module")
def one_worker(random_models):
    return outcomes("process", 1, random_models["vi"])


def test_one_and_two_worker_processes_agree(one_worker, random_models):
    assert [r.seed for r in one_worker[1]] == list(range(500, 506))
    assert len({r.steps for r in one_worker[1]} | {len(r.x) for r in one_worker[1]}) > 1  # paths differ by seed
    assert_same(one_worker, outcomes("process", 2, random_models["vi"]))


@pytest.mark.slow
def test_ray_backend_agrees_with_the_process_pool(one_worker, random_models):
    pytest.importorskip("ray")
    assert_same(one_worker, outcomes("ray", 2, random_models["vi"]))


def test_unknown_backend_and_bad_worker_count_fail_before_any_rollout(random_models):
    with pytest.raises(ValueError, match=r"executor.name='dask' is not a known backend; choose one of \['process', 'ray'\]"):
        make_executor("dask", job(random_models["vi"]), 2)
    with pytest.raises(ValueError, match="executor.workers=0 must be an integer >= 1"):
        make_executor("process", job(random_models["vi"]), 0)
