"""A cell's progress bar moves per rollout, as the workers finish them, not per chunk of rollouts when the chunk
returns (a single cell of 32 rollouts used to sit still, then jump)."""

import tempfile
import time
from pathlib import Path

from conftest import CONF

from uqdrive.data.binning import SteeringBins
from uqdrive.parallel import ProcessPool, report
from uqdrive.policy.recipes import ControllerSpec
from uqdrive.safety import executors, runner
from uqdrive.safety.cells import EstimatorSettings
from uqdrive.safety.executors import RolloutJob
from uqdrive.safety.runner import CellRunner
from uqdrive.sim import ScenarioConfig, WeatherConfig
from uqdrive.sim.condition import Condition

PARTS, PAUSE = 3, 0.3


class SlowItems:
    """A job whose item is ``PARTS`` parts of ``PAUSE`` s each, each reported as it ends."""

    def worker(self):
        return self

    def run(self, item):
        for _ in range(PARTS):
            time.sleep(PAUSE)
            report()
        return item

    def close(self):
        pass


def test_a_pool_hears_each_part_of_an_item_before_the_item_returns():
    heard: list[float] = []
    with ProcessPool(2) as pool:
        executor = pool.executor(SlowItems())
        assert executor.on_report(lambda done: heard.append(time.perf_counter()))
        start = time.perf_counter()
        first = next(iter(executor.run([0, 1])))
        returned = time.perf_counter()
        executor.close()
    assert first == 0
    early = [t for t in heard if t < returned]
    assert len(early) >= PARTS - 1, (len(early), [t - start for t in heard], returned - start)


def test_a_cells_bar_ticks_once_per_rollout_from_inside_the_workers_chunk(random_models, monkeypatch):
    """In one process the ticks can be watched: each comes while the chunk's rollouts still run."""
    ticks: list[tuple[int, bool]] = []
    inside = {"now": False}
    lockstep = executors.run_rollouts

    def watched(*args, **kwargs):
        inside["now"] = True
        try:
            return lockstep(*args, **kwargs)
        finally:
            inside["now"] = False

    class Bar:
        def __init__(self, **kwargs):
            pass

        def update(self, n=1):
            ticks.append((n, inside["now"]))

        def close(self):
            pass

    monkeypatch.setattr(executors, "run_rollouts", watched)
    monkeypatch.setattr(runner, "tqdm", Bar)
    spec = ControllerSpec(6.0, str(random_models["vi"]), "vi", SteeringBins(), samples=10, eps=0.1)
    roundabout = ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout.yaml")
    clear = WeatherConfig.from_yaml(CONF / "weather" / "clear_noon.yaml")
    settings = EstimatorSettings("chernoff", 0.6, 0.05, 500)  # 6 rollouts
    job = RolloutJob(spec, Condition(roundabout, clear, 0.0), base_seed=settings.base_seed)
    with tempfile.TemporaryDirectory() as log, CellRunner("process", 1, progress=True) as cells:
        run = cells.estimate("cell", job, settings, "key", Path(log) / "cell.jsonl")
    fresh = [t for t in ticks if t != (0, False)]  # the replayed rollouts' tick (none here) is 0
    assert len(run.results) == 6 and fresh == [(1, True)] * 6, ticks
