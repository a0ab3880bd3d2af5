"""A second Gymnasium world with its own expert beside HighwayEnv's, added as a user adds one: a tiny env and its
hooks (tests/wind_kit.py), the world's conf with its own condition axis (tests/worlds/gym_world/wind_lane.yaml) and
its experiment (tests/worlds/experiment/wind_lane.yaml), found through Hydra's search path. Collected from its own
expert, trained on the tiny profile, swept over its axis by the Gymnasium safety sweep: nothing of HighwayEnv's (nor
any global axis) enters. What it takes: those four files (and, to run it in `dvc repro`, its name in params.yaml's
gym_worlds)."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_stage_sweeps import sweep

from uqdrive.pipeline.collect_stage import run_collect
from uqdrive.pipeline.preprocess_stage import run_preprocess
from uqdrive.pipeline.safety_stage import run_safety_sweep
from uqdrive.pipeline.train_stage import run_train

pytestmark = pytest.mark.filterwarnings("ignore:.*Overriding environment wind_kit")  # registered on each import
SEARCH = f"hydra.searchpath=[file://{Path(__file__).resolve().parent / 'worlds'}]"  # the world's own conf
WORLD = (SEARCH, "gym_world=wind_lane")
EXPERIMENT = (SEARCH, "experiment=wind_lane")  # named after the world: trained on its frames alone


@pytest.mark.slow
def test_a_second_world_with_its_own_expert_and_axis_is_collected_trained_and_swept(stage_config, tmp_path):
    collection = run_collect(stage_config("collect", *WORLD, "collect.workers=1", "collect.episodes=4"))
    assert (collection.episodes, collection.frames) == (4, 4 * 12)  # its expert, its horizon
    run_preprocess(stage_config("preprocess", *EXPERIMENT))
    run_train(stage_config("train", *EXPERIMENT, "model=mcd"))
    grid = ("sweep.methods=[mcd]", "sweep.replicates=[0]", "sweep.noises=[0.0]", "executor.workers=1")
    cells = sweep(run_safety_sweep, "gym_safety_sweep", tmp_path, *WORLD, "experiment=wind_lane", *grid)
    assert [(config.gym_world.env_kwargs.wind, c["location"]) for config, c in cells] == [
        (0.05, "wind_lane-calm"),  # the axis of its own conf (gym_world.axis), the first as collected
        (0.5, "wind_lane-gale"),
    ]
    gale = cells[1][1]
    assert gale["outcomes"] == "0" * gale["n"] and gale["off_road_rate"] == 1.0  # no steer holds 0.5 m a step
    assert all(c["weather"] == "env" and c["experiment"] == "wind_lane" for _, c in cells)
