"""The closed-loop stages in a Gymnasium world (`gym_world=<conf/gym_world/ file>`): a safety cell through
`run_safety` on a stub env whose crash rate is known, HighwayEnv's roundabout end to end, a condition the env lacks
refused in one line, the cell identity over the env's kwargs and packages, a sweep over one of the env's conditions,
expert data collected in the world."""

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import ALL_TENTHS
from mlflow.tracking import MlflowClient
from test_gym_world import COIN_ID, CRASH_RATE, coin_crash_step
from test_stage_sweeps import sweep

import uqdrive.safety.runner as runner
import uqdrive.sim.location as sim_location
from uqdrive.avoid.plan import build_settings
from uqdrive.avoid.results import Mode
from uqdrive.pipeline.avoid_stage import run_avoid
from uqdrive.pipeline.collect_stage import run_collect
from uqdrive.pipeline.envelope_stage import run_envelope
from uqdrive.pipeline.findings_stage import run_findings
from uqdrive.pipeline.safety_stage import plan_cell, run_safety, run_safety_sweep
from uqdrive.schema import ConfigError
from uqdrive.tracking import store_uris
from uqdrive.uq import clopper_pearson_interval

ROOT = Path(__file__).resolve().parents[1]
COIN = (
    "gym_world=uqdrive_roundabout",
    f"gym_world.env_id={COIN_ID}",
    "gym_world.name=coin",
    "gym_world.horizon_steps=12",
)
COIN_RATE = f"++gym_world.env_kwargs.rate={CRASH_RATE}"  # the known world sets the key its conditions change


@pytest.fixture
def gym_safety(stage_config, random_models):
    """A safety cell's config in a Gymnasium world, driving the random-weight models (overrides appended)."""

    def make(*overrides: str):
        model = f"safety.model_path={random_models['mcd'].parent}/${{model.name}}.pt"
        return stage_config("safety", model, *ALL_TENTHS, *overrides)

    return make


def test_a_gym_cell_through_the_stage_is_each_seeds_coin_and_its_exact_interval_covers_the_rate(gym_safety, tmp_path):
    cfg = gym_safety(*COIN, "safety.scheme=clopper_pearson", "safety.theta=0.15", "executor.workers=1")
    cell = run_safety(cfg).cell
    seeds = range(cell.base_seed, cell.base_seed + cell.estimate.n)
    assert cell.outcomes == "".join("0" if coin_crash_step(s, CRASH_RATE) else "1" for s in seeds)  # each run's own
    assert (cell.location, cell.weather, cell.estimate.scheme, cell.estimate.guaranteed) == (
        "coin",
        "env",
        "clopper_pearson",
        True,
    )
    assert (cell.estimate.low, cell.estimate.high) == clopper_pearson_interval(
        cell.outcomes.count("1"), cell.estimate.n, 0.05
    )
    assert cell.estimate.low <= 1 - CRASH_RATE <= cell.estimate.high and cell.collision_rate == pytest.approx(
        1 - cell.estimate.value
    )
    assert (tmp_path / "metrics/safety/mcd-seed0-coin-env-noise0.0.json").exists()
    assert (tmp_path / "plots/safety/cells/mcd-seed0-coin-env-noise0.0.png").stat().st_size > 5000
    assert run_safety(cfg).reused


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("weather=rain", f"weather='rain': {COIN_ID} has no weather condition (the world is the env)"),
        ("scenario=roundabout", f"scenario='roundabout': {COIN_ID} has no scenario condition (the world is the env)"),
        ("safety.half_width=2", "safety.half_width=2.0 is a lane's: a gym_world is judged by its safe_if"),
        ("gym_world.env_id=nowhere.envs:No-v0", "gym_world.env_id='nowhere.envs:No-v0': No module named 'nowhere'"),
        (
            "safety.model_path=/nonexistent/mcd.pt",
            "safety.model_path=/nonexistent/mcd.pt does not exist; train it first: dvc repro train_mcd@offline",
        ),
    ],
)
def test_a_condition_the_env_lacks_is_refused_in_one_line_before_anything_is_written(
    gym_safety, tmp_path, override, message
):
    with pytest.raises(ConfigError) as err:
        run_safety(gym_safety(*COIN, override))
    assert str(err.value) == message
    assert list(tmp_path.iterdir()) == []


def test_the_sweep_refuses_the_pybullet_worlds_axes_beside_a_gym_world(stage_config, tmp_path):
    shutil.copy(ROOT / "params.yaml", tmp_path / "params.yaml")
    with pytest.raises(ConfigError, match=r"^sweep.weathers=\['rain'\] must be empty: .* is the world$"):
        next(run_safety_sweep(stage_config("gym_safety_sweep", *COIN, "sweep.weathers=[rain]"), []))


def test_the_sweep_refuses_an_axis_over_a_key_the_world_does_not_set_in_one_line(stage_config, tmp_path):
    shutil.copy(ROOT / "params.yaml", tmp_path / "params.yaml")
    axis = "sweep.world_axis={key: env_kwargs.rat, values: {calm: 0.1}}"  # misspelt: an identical world otherwise
    with pytest.raises(ConfigError, match=r"^sweep.world_axis.env_kwargs.rat: gym_world 'coin' sets no env_kwargs.rat"):
        next(run_safety_sweep(stage_config("gym_safety_sweep", *COIN, COIN_RATE, axis), []))


def test_the_cell_identity_covers_the_envs_kwargs_its_packages_and_the_modules_it_loads_by_name(
    gym_safety, monkeypatch
):
    key = plan_cell(gym_safety(*COIN)).key
    assert plan_cell(gym_safety(*COIN)).key == key
    assert plan_cell(gym_safety(*COIN, "++gym_world.env_kwargs.rate=0.5")).key != key  # another crash rate
    assert plan_cell(gym_safety(*COIN, "gym_world.safe_if.off_road=true")).key != key
    job = plan_cell(gym_safety(*COIN)).job
    assert runner.job_identity(job)["where"]["gym_world"]["packages"]["gymnasium"] == "1.4.0"
    real = sim_location.world_identity
    monkeypatch.setattr(sim_location, "world_identity", lambda c: {**real(c), "packages": {"gymnasium": "9.9"}})
    assert plan_cell(gym_safety(*COIN)).key != key  # another Gymnasium: another cell
    digested: list = []
    monkeypatch.setattr(runner, "code_digest", lambda modules: digested.append(modules) or "digest")
    pytest.importorskip("highway_env", reason="highway-env is not installed (pip install 'uqdrive[highway]')")
    plan_cell(gym_safety("gym_world=highway_roundabout"))
    assert {"uqdrive.sim.gym_world", "uqdrive.sim.gym_highway"} <= set(digested[-1])


def test_a_sweep_over_one_of_the_envs_conditions_makes_each_value_a_location_and_the_findings_test_them(
    random_models, stage_config, tmp_path
):
    shutil.copy(ROOT / "params.yaml", tmp_path / "params.yaml")
    model = f"safety.model_path={random_models['mcd'].parent}/${{model.name}}.pt"
    axis = "sweep.world_axis={key: env_kwargs.rate, values: {calm: 0.1, wild: 0.9}}"
    grid = ("sweep.methods=[mcd,vi]", "sweep.replicates=[0]", "sweep.noises=[0.0]", axis)
    cells = sweep(run_safety_sweep, "gym_safety_sweep", tmp_path, model, *ALL_TENTHS, *COIN, COIN_RATE, *grid)
    assert [(c["method"], c["location"]) for _, c in cells] == [
        ("mcd", "coin-calm"),
        ("mcd", "coin-wild"),
        ("vi", "coin-calm"),
        ("vi", "coin-wild"),
    ]
    for (config, cell), rate in zip(cells, (0.1, 0.9, 0.1, 0.9)):
        seeds = range(cell["base_seed"], cell["base_seed"] + cell["n"])
        assert config.gym_world.env_kwargs.rate == rate
        assert cell["outcomes"] == "".join("0" if coin_crash_step(s, rate) else "1" for s in seeds)
    assert cells[0][1]["config_hash"] != cells[1][1]["config_hash"]

    unknown = stage_config("gym_avoid", "gym_world=highway_roundabout").avoid.unknown  # its axis' values but the first
    assert [(u["name"], u["world"]) for u in unknown] == [
        ("aggressive", {"env_kwargs.config.other_vehicles_type": "highway_env.vehicle.behavior.AggressiveVehicle"})
    ]
    for method in ("mcd", "vi"):  # the warning system in the same world, its unknown condition the wild coin
        avoid = ("experiment.name=coin", f"model={method}", "avoid.unknown=[{name:wild,world:{env_kwargs:{rate:0.9}}}]")
        run_avoid(stage_config("gym_avoid", *ALL_TENTHS, *COIN, COIN_RATE, *avoid, model.replace("safety.", "avoid.")))
    assert (tmp_path / "metrics/coin/avoid/vi-seed0.json").exists()

    assert stage_config("gym_findings").locations == ["highway_roundabout-idm", "highway_roundabout-aggressive"]
    cells_dir = f"findings.cells_dir={tmp_path}/metrics/safety"
    grid = ("world=coin", "locations=[coin-calm,coin-wild]", "methods=[mcd,vi]", "replicates=[0]", "noises=[0.0]")
    findings = run_findings(stage_config("gym_findings", *grid, cells_dir))
    names = [f.finding.name for f in findings.findings]
    assert names[:4] == ["mcd vs vi at coin-calm-env-noise0.0", "mcd vs vi at coin-wild-env-noise0.0"] + [
        f"{m}: coin-wild-env-noise0.0 vs the training condition" for m in ("mcd", "vi")
    ]
    assert {f"{m}: on vs off at {c}" for m in ("mcd", "vi") for c in ("known", "wild")} <= set(names), names
    assert {f.experiment for f in findings.findings} == {"coin"} and {c.family for c in findings.claims} == {
        "exploratory"
    }
    assert (tmp_path / "metrics/coin/findings.json").exists()


@pytest.fixture
def highway(gym_safety):
    pytest.importorskip("highway_env", reason="highway-env is not installed (pip install 'uqdrive[highway]')")
    return gym_safety


def test_highway_roundabout_runs_a_tiny_safety_cell_end_to_end_through_the_stage(highway, tmp_path):
    cfg = highway("gym_world=highway_roundabout", "gym_world.horizon_steps=15", "noise=0.05")
    result = run_safety(cfg)
    cell = result.cell
    assert not result.reused and cell.estimate.n == 4 and len(cell.outcomes) == 4  # chernoff_n(0.7, 0.05)
    assert (cell.location, cell.weather, cell.noise) == ("highway_roundabout", "env", 0.05)
    assert cell.steps <= 4 * 15 and cell.max_corridor_use is None  # no corridor: no run measured it
    saved = json.loads((tmp_path / "metrics/safety/mcd-seed0-highway_roundabout-env-noise0.05.json").read_text())
    assert saved["outcomes"] == cell.outcomes
    client = MlflowClient(store_uris(tmp_path)[0])
    (run,) = client.search_runs([client.get_experiment_by_name("uqdrive/safety").experiment_id])
    assert run.data.params["location"] == "highway_roundabout" and "weather" not in run.data.params
    again = run_safety(highway("gym_world=highway_roundabout", "gym_world.horizon_steps=15", "noise=0.05"))
    assert again.reused and again.cell.outcomes == cell.outcomes


@pytest.mark.slow
def test_highway_roundabouts_warning_system_runs_end_to_end_with_aggressive_drivers_as_the_unknown(
    stage_config, random_models, tmp_path
):
    pytest.importorskip("highway_env", reason="highway-env is not installed (pip install 'uqdrive[highway]')")
    shutil.copy(ROOT / "params.yaml", tmp_path / "params.yaml")  # its axis: IDM as collected, then aggressive
    model = f"avoid.model_path={random_models['mcd'].parent}/${{model.name}}.pt"
    world = ("gym_world=highway_roundabout", "gym_world.horizon_steps=15")
    cfg = stage_config("gym_avoid", model, *ALL_TENTHS, *world)
    known, (aggressive,) = build_settings(cfg).known, build_settings(cfg).unknown
    drivers = [c.scenario.env_kwargs["config"]["other_vehicles_type"].rpartition(".")[2] for c in (known, aggressive)]
    assert drivers == ["IDMVehicle", "AggressiveVehicle"] and aggressive.location == "highway_roundabout-aggressive"
    result = run_avoid(cfg)
    assert result.conditions == ["known", "aggressive"] and result.horizon_s == 1.0
    assert {len(result.cells[c][m].outcomes) for c in result.conditions for m in Mode} == {4}  # every cell ran
    assert (tmp_path / "metrics/avoid/avoid/mcd-seed0.json").exists()  # under the experiment's own folder


def test_collect_records_the_worlds_own_expert_in_grey_network_frames(stage_config, tmp_path):
    pytest.importorskip("highway_env", reason="highway-env is not installed (pip install 'uqdrive[highway]')")
    cfg = stage_config("collect", "gym_world=highway_roundabout", "gym_world.horizon_steps=10", "collect.workers=1")
    collection = run_collect(cfg)
    assert (collection.episodes, collection.frames) == (2, 20)  # tiny: 2 episodes of 10 steps
    assert (collection.render_width, collection.render_height) == (64, 48)
    table = pq.read_table(tmp_path / "data/raw/highway_roundabout.parquet").to_pydict()
    assert set(table["scenario"]) == {"highway_roundabout"} and set(table["weather"]) == {"env"}
    assert all(-1 <= s <= 1 for s in table["steering"]) and table["seed"][0] == 1000


def test_collect_refuses_a_world_whose_hooks_know_no_expert_before_any_work(stage_config, tmp_path):
    with pytest.raises(ConfigError) as err:
        run_collect(stage_config("collect", "gym_world=uqdrive_roundabout"))
    assert str(err.value).startswith("gym_world.hooks='info': uqdrive.sim.gym_env:uqdrive/Roundabout-v0 has no expert")
    assert list(tmp_path.iterdir()) == []


RATE_AXES = "envelope.axes=[{key:noise,range:[0,0.1]},{key:gym_world.env_kwargs.rate,range:[0,1]}]"


@pytest.mark.slow
def test_the_envelope_maps_a_gym_world_over_a_number_of_its_config_and_each_verdict_holds_for_its_region(
    stage_config, random_models, tmp_path
):
    """The coin env's crash rate as an axis: a region's η1 averaged over it is 1 − its mean rate, whatever the
    network (every run ends at the coin), so each verdict is checked against the truth."""
    model = f"envelope.model_path={random_models['mcd'].parent}/${{model.name}}.pt"
    budgets = ("envelope.threshold=0.5", "envelope.certify_budget=null", "++gym_world.env_kwargs.rate=0.5")
    cfg = stage_config("envelope", model, *ALL_TENTHS, *COIN, RATE_AXES, *budgets, "executor.workers=1")
    result = run_envelope(cfg).result
    assert [a.key for a in result.axes] == ["noise", "gym_world.env_kwargs.rate"]
    decided = [r for r in result.regions if r.verdict != "undecided"]
    assert {"safe", "unsafe"} <= {r.verdict for r in decided}, [r.verdict for r in result.regions]
    for region in decided:
        low, high = region.bounds["gym_world.env_kwargs.rate"]
        assert (region.verdict == "safe") == (1 - (low + high) / 2 >= 0.5), region
    assert (tmp_path / "plots/envelope/mcd-seed0/map.png").stat().st_size > 5000


def test_an_envelope_cell_in_a_gym_world_holds_the_worlds_identity_and_code(stage_config, random_models, monkeypatch):
    from uqdrive.envelope.plan import build_envelope

    model = f"envelope.model_path={random_models['mcd'].parent}/${{model.name}}.pt"
    envelope = build_envelope(stage_config("envelope", model, *ALL_TENTHS, *COIN, COIN_RATE, RATE_AXES))
    job = envelope.job(envelope.uniform_in((0.0, 0.0), (1.0, 1.0)), 0)
    where = runner.job_identity(job)["where"]
    assert set(where["gym_world"]["packages"]) >= {"gymnasium"} and where["gym_world"]["config"]["name"] == "coin"
    digested = []
    monkeypatch.setattr(runner, "code_digest", lambda modules: digested.append(modules) or "x")
    runner.cell_key(job, {}, None, __name__)
    assert "uqdrive.sim.gym_world" in digested[-1]  # the modules the world loads by name


@pytest.mark.parametrize(
    ("axes", "message"),
    [
        ("[{key:noise,range:[0,0.1]},{key:weather.fog_density,range:[0,1]}]", "envelope.axes: weather.fog_density is"),
        (
            "[{key:noise,range:[0,0.1]},{key:gym_world.horizon_steps,range:[10,20]}]",
            f"envelope.axes: gym_world.horizon_steps: a condition of {COIN_ID} is a key of its env_kwargs",
        ),
        (
            "[{key:noise,range:[0,0.1]},{key:gym_world.env_kwargs.rat,range:[0,1]}]",
            "envelope.axes: gym_world.env_kwargs.rat: gym_world 'coin' sets no env_kwargs.rat",
        ),
    ],
)
def test_an_envelope_axis_the_gym_world_lacks_is_refused_in_one_line(
    stage_config, random_models, tmp_path, axes, message
):
    model = f"envelope.model_path={random_models['mcd'].parent}/${{model.name}}.pt"
    with pytest.raises(ConfigError) as err:
        run_envelope(stage_config("envelope", model, *ALL_TENTHS, *COIN, COIN_RATE, f"envelope.axes={axes}"))
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_an_envelope_axis_over_a_gym_world_without_one_is_refused_in_one_line(stage_config, random_models):
    model = f"envelope.model_path={random_models['mcd'].parent}/${{model.name}}.pt"
    with pytest.raises(ConfigError, match=r"^envelope.axes: gym_world.env_kwargs.rate varies a gym_world; name one"):
        run_envelope(stage_config("envelope", model, *ALL_TENTHS, RATE_AXES))


RISKY = "avoid.unknown=[{name:risky,world:{env_kwargs:{rate:0.7}}}]"  # the coin env with another crash rate


@pytest.mark.slow
def test_the_avoid_stage_runs_in_a_gym_world_whose_unknown_condition_is_the_world_changed(avoid_config, tmp_path):
    cfg = avoid_config(*COIN, COIN_RATE, RISKY, "executor.workers=1", "avoid.min_rollouts=12")
    result = run_avoid(cfg)
    assert result.conditions == ["known", "risky"] and result.horizon_s == pytest.approx(12 / 15)
    for condition, rate in (("known", CRASH_RATE), ("risky", 0.7)):
        off = result.cells[condition][Mode.OFF]
        seeds = range(off.base_seed, off.base_seed + 12)  # warnings off: each run is its seed's coin
        assert off.outcomes == "".join("0" if coin_crash_step(s, rate) else "1" for s in seeds)
        assert off.passed_rate == off.outcomes.count("1") / 12  # the safe runs drove to the horizon
        on = result.cells[condition][Mode.ON]  # the same runs until a hand-over stops them: never less safe
        assert on.terminations["handover"] > 0 and set(on.terminations) <= {"timeout", "collision", "handover"}
        assert all(a >= b for a, b in zip(on.outcomes, off.outcomes)), (on.outcomes, off.outcomes)
    saved = json.loads((tmp_path / "metrics/avoid/mcd-seed0.json").read_text())
    assert saved["calibration"]["certificate"]["calibration_runs"] == {"known": 12, "risky": 12}
    with np.load(tmp_path / "data/avoid/mcd-seed0/traces/mcd-seed0-risky-off.npz") as data:
        assert data["obstacle"].size == 0 and (np.diff(data["distance"][data["rollout"] == 0]) < 0).all()
    for name in ("trajectories", "warnings", "tradeoff"):
        assert (tmp_path / f"plots/avoid/mcd-seed0/{name}.png").stat().st_size > 5000
    (risky,) = build_settings(cfg).unknown  # the world changed, as a location of its own
    assert (risky.location, risky.scenario.env_kwargs, risky.weather_name) == ("coin-risky", {"rate": 0.7}, "env")


def test_a_gym_worlds_unknown_conditions_as_one_mixture_draw_each_runs_world_and_keep_its_identity(avoid_config):
    two = "avoid.unknown=[{name:calm,world:{env_kwargs.rate:0.1}},{name:wild,world:{env_kwargs.rate:0.9}}]"
    settings = build_settings(avoid_config(*COIN, COIN_RATE, two, "avoid.unknown_as=mixture"))
    (mixture,) = settings.unknown
    job = settings.job(mixture, None, settings.estimator.base_seed)
    rates = {job.condition(i).scenario.env_kwargs["rate"] for i in range(16)}
    assert rates == {0.1, 0.9} and [v.location for v in mixture.variants] == ["coin-calm", "coin-wild"]
    variants = runner.job_identity(job)["where"]["variants"]
    assert [v["gym_world"]["config"]["env_kwargs"] for v in variants] == [{"rate": 0.1}, {"rate": 0.9}]


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (("avoid.unknown=[{name:fog,weather:fog}]",), "avoid.unknown[0].weather='fog' is uqdrive's: "),
        (
            ("avoid.unknown=[{name:x,world:{horizon_steps:9}}]",),
            f"avoid.unknown[0].world.horizon_steps: a condition of {COIN_ID} is a key of its env_kwargs",
        ),
        (
            ("avoid.unknown=[{name:x,world:{env_kwargs.rat:0.5}}]",),  # misspelt: the world sets no such key
            "avoid.unknown[0].world.env_kwargs.rat: gym_world 'coin' sets no env_kwargs.rat",
        ),
    ],
)
def test_a_gym_worlds_unknown_condition_of_ours_or_a_bad_change_is_refused_in_one_line(
    avoid_config, tmp_path, overrides, message
):
    with pytest.raises(ConfigError) as err:
        run_avoid(avoid_config(*COIN, COIN_RATE, *overrides))
    assert str(err.value).startswith(message) and "\n" not in str(err.value)
    assert list(tmp_path.iterdir()) == []


def test_a_world_change_without_a_gym_world_is_refused_in_one_line(avoid_config, tmp_path):
    with pytest.raises(ConfigError, match=r"^avoid.unknown\[0\].world=\{'horizon_steps': 3\} changes a gym_world"):
        run_avoid(avoid_config("avoid.unknown=[{name:x,world:{horizon_steps:3}}]"))


def test_a_missing_model_names_the_stage_that_trains_its_experiment_whatever_world_drives_it():
    from uqdrive.sim.config import names_gym_world
    from uqdrive.stage_schemas import training_stage

    assert not names_gym_world("offline") and training_stage("offline", "vi") == "train@offline-vi"  # pybullet's
    world = "highway_roundabout"  # an experiment named after a Gymnasium world trains in the gym_ stages
    assert names_gym_world(world)
    assert training_stage(world, "mcd", True) == f"gym_train_mcd@{world} (with {world} in params.yaml's gym_worlds)"
