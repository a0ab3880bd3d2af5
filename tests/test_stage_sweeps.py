"""The DVC stages that run a grid of cells in one process on one pool (uqdrive.stage): `safety` and
`heldout` give every cell the result, files and config hash its single-cell command gives it."""

import shutil

import pyarrow.parquet as pq
import pytest
from conftest import ALL_TENTHS, CONF, cell_result
from hydra import compose, initialize_config_dir
from mlflow.tracking import MlflowClient

from uqdrive.pipeline.collect_stage import run_collect
from uqdrive.pipeline.heldout_stage import run_heldout
from uqdrive.pipeline.safety_stage import run_safety, run_safety_sweep
from uqdrive.records import as_dict
from uqdrive.schema import ConfigError
from uqdrive.stage import cell_overrides, grid
from uqdrive.tracking import store_uris
from uqdrive.uq import chernoff_n

SWEEP = (
    "sweep.methods=[vi,mcd]",
    "sweep.replicates=[0]",
    "sweep.locations=[roundabout]",
    "sweep.weathers=[clear_noon]",
    "sweep.noises=[0,0.1]",
)


@pytest.fixture
def models(random_models):
    return (f"safety.model_path={random_models['mcd'].parent}/${{model.name}}.pt", *ALL_TENTHS)


def sweep(run, config_name, root, *overrides):
    args = [f"paths.root={root}", "profile=tiny", "progress=false", *overrides]
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return [(cell, flat(result)) for cell, result in run(compose(config_name, args), args)]


def flat(result):
    """A finished cell as its record's keys plus ``reused`` (a collection: its record's keys)."""
    if hasattr(result, "cell"):
        return {**as_dict(result.cell), "reused": result.reused}
    return as_dict(result)


def test_grid_varies_the_last_axis_fastest_and_a_cell_overrides_the_sweep():
    assert grid(a=[1, 2], b=["x", "y"]) == [
        {"a": 1, "b": "x"},
        {"a": 1, "b": "y"},
        {"a": 2, "b": "x"},
        {"a": 2, "b": "y"},
    ]
    overrides = [
        "profile=quick",
        "weather=fog",
        "sweep.weathers=[rain]",
        "~sweep.noises",
        "++sweep.x=1",
        "safety.theta=0.1",
    ]
    assert cell_overrides(overrides, {"weather": "rain", "noise": 0.1}) == [
        "profile=quick",
        "safety.theta=0.1",
        "weather=rain",
        "noise=0.1",
    ]


def test_a_sweep_with_a_missing_model_stops_before_its_first_cell(tmp_path, random_models):
    only_mcd = tmp_path / "models"
    only_mcd.mkdir()
    shutil.copy(random_models["mcd"], only_mcd / "mcd.pt")  # vi, swept after mcd, was never trained
    grid = (f"safety.model_path={only_mcd}/${{model.name}}.pt", *ALL_TENTHS, *SWEEP[1:], "sweep.methods=[mcd,vi]")
    with pytest.raises(ConfigError, match=rf"^safety.model_path={only_mcd}/vi.pt does not exist; train it first"):
        sweep(run_safety_sweep, "safety_sweep", tmp_path, *grid)
    assert not (tmp_path / "metrics").exists() and not (tmp_path / "cache").exists()  # no cell ran


@pytest.mark.slow
def test_safety_sweep_runs_every_cell_as_the_single_cell_command(tmp_path, models, stage_config):
    swept = sweep(run_safety_sweep, "safety_sweep", tmp_path, *models, "executor.workers=2", *SWEEP)
    assert [cell.safety.cell for cell, _ in swept] == [
        f"{m}-seed0-roundabout-clear_noon-noise{n}" for m in ("vi", "mcd") for n in ("0.0", "0.1")
    ]
    assert all(not r["reused"] and r["n"] == 4 for _, r in swept)
    # the single-cell command composes the same config: same hash, so it reuses the sweep's result as it is
    cell, last = swept[-1]
    assert flat(run_safety(stage_config("safety", *models, "model=mcd", "noise=0.1"))) == {**last, "reused": True}
    # run afresh in one process elsewhere, it drives the rollouts the shared pool drove (whose processes had
    # dropped the worlds of the cells before)
    elsewhere = tmp_path / "single"
    fresh = flat(
        run_safety(
            stage_config("safety", f"paths.root={elsewhere}", *models, "model=mcd", "noise=0.1", "executor.workers=1")
        )
    )
    assert cell_result(fresh) == cell_result(last)
    table = f"plots/safety/cells/{cell.safety.cell}.csv"
    assert (elsewhere / table).read_text() == (tmp_path / table).read_text()
    # DVC removes the stage's outputs before it reruns it: every cell is replayed from its rollout log, nothing is
    # simulated, the results are the same and the runs say so
    shutil.rmtree(tmp_path / "metrics/safety")
    again = sweep(run_safety_sweep, "safety_sweep", tmp_path, *models, "executor.workers=2", *SWEEP)
    assert [r["reused"] for _, r in again] == [True] * 4
    assert [{k: v for k, v in r.items() if k not in ("seconds", "reused")} for _, r in again] == [
        {k: v for k, v in r.items() if k not in ("seconds", "reused")} for _, r in swept
    ]
    client = MlflowClient(store_uris(tmp_path)[0])
    logged = client.search_runs([client.get_experiment_by_name("uqdrive/safety").experiment_id])
    cells = [r for r in logged if "reused" in r.data.tags]
    assert sorted(r.data.tags["reused"] for r in cells) == ["false"] * 4 + ["true"] * 5  # and the single-cell reuse
    parents = {r.info.run_id for r in logged} - {r.info.run_id for r in cells}  # one per sweep run
    assert len(parents) == 2 and all(
        r.info.run_name == "adhoc · sweep of 4 cells" for r in logged if r.info.run_id in parents
    )
    assert sorted(r.data.tags.get("mlflow.parentRunId") in parents for r in cells) == [False] + [True] * 8


@pytest.mark.slow
def test_heldout_sweep_collects_every_condition_as_the_single_condition_command(tmp_path, stage_config):
    swept = sweep(run_heldout, "heldout_sweep", tmp_path, "sweep.weathers=[clear_noon,rain]", "sweep.noises=[0.1]")
    assert [cell.collect.name for cell, _ in swept] == [
        "heldout-roundabout-clear_noon-noise0.1",
        "heldout-roundabout-rain-noise0.1",
    ]
    assert (tmp_path / "metrics/heldout/roundabout-rain-noise0.1.json").exists()
    assert (tmp_path / "plots/heldout/roundabout-rain-noise0.1_mosaic.png").exists()
    elsewhere = tmp_path / "single"
    run_collect(stage_config("heldout", f"paths.root={elsewhere}", "weather=rain", "noise=0.1", "collect.workers=1"))
    table = "data/heldout/roundabout-rain-noise0.1.parquet"
    assert pq.read_table(elsewhere / table).equals(pq.read_table(tmp_path / table))


def test_a_weather_without_a_config_fails_before_any_cell(tmp_path, models):
    with pytest.raises(
        ConfigError, match=r"^sweep cell model=vi seed=0 scenario=roundabout weather=foggy noise=0.0: .*foggy"
    ):
        sweep(
            run_safety_sweep,
            "safety_sweep",
            tmp_path,
            *models,
            *SWEEP[:3],
            "sweep.weathers=[clear_noon,foggy]",
            "sweep.noises=[0]",
        )
    assert not (tmp_path / "metrics").exists() and not (tmp_path / "mlflow.db").exists()


@pytest.mark.slow
def test_a_family_wise_sweep_spends_gamma_over_its_cells(tmp_path, models, stage_config):
    """Each of the m cells at γ/m (Bonferroni): every interval holds at once with probability ≥ 1 − γ. The cell
    records say so, and the single-cell command given the same family reuses the sweep's cell."""
    swept = sweep(run_safety_sweep, "safety_sweep", tmp_path, *models, *SWEEP, "safety.family_wise=true")
    assert [(r["family_size"], r["gamma"]) for _, r in swept] == [(4, 0.05 / 4)] * 4
    assert all(r["n"] == chernoff_n(0.7, 0.05 / 4) for _, r in swept)  # more runs per cell than at γ
    single = stage_config(
        "safety", *models, "model=mcd", "noise=0.1", "safety.family_wise=true", "safety.family_size=4"
    )
    assert flat(run_safety(single))["reused"]
    with pytest.raises(ValueError, match=r"^safety.family_size=4 must be 1 unless safety.family_wise$"):
        flat(run_safety(stage_config("safety", *models, "safety.family_size=4")))
