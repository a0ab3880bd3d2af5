"""The acquire stage (DAgger aimed by the safety sweep): acquired labels are the expert's command in the visited
state, a round is a function of its settings, round 0's retraining is behaviour cloning bit for bit, and the
targeted sampler acquires only where the sweep flagged the controller plus the training condition."""

import dataclasses
import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch
from hydra import compose, initialize_config_dir
from test_train import write_processed

from uqdrive.acquire.acquisition import AcquisitionCheck, before_after, flagged_cells
from uqdrive.acquire.plan import AcquireStage, Where, placed
from uqdrive.data.binning import SteeringBins
from uqdrive.data.tables import RAW_SCHEMA
from uqdrive.models.checkpoint import read_checkpoint
from uqdrive.pipeline.acquire_stage import aggregate, as_swept, retrain, rounds_key, run_acquire, targeted_conditions
from uqdrive.pipeline.safety_stage import run_safety
from uqdrive.pipeline.train_stage import run_train
from uqdrive.records import read_record, write_record
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.safety.plan import SafetyStage
from uqdrive.schema import ConfigError, validate
from uqdrive.sim import Autopilot, AutopilotConfig, build_geometry
from uqdrive.uq.bounds import chernoff_n, clopper_pearson_n
from uqdrive.uq.estimators import Estimate
from uqdrive.uq.paired import non_inferior, paired_table

CONF = Path(__file__).resolve().parents[1] / "conf"
ALL_TENTHS = ("experiment.bins.low=-1.0", "experiment.bins.high=1.0")  # the synthetic frames' labels span ±0.6
TRAINING = Where("roundabout", "clear_noon", 0.0)
# one round, one short episode per condition: the tiny safety cells (4 rollouts of at most 12 s) check it
TINY = (
    "experiment=offline",
    "outputs=pipeline",
    *ALL_TENTHS,
    "acquire.episodes=1",
    "safety.horizon_s=6",
    "train.mcd.epochs=1",
    "acquire.checks=[{location: roundabout_town, weather: clear_noon, noise: 0.0}]",  # never acquired at
    "acquire.check_theta=null",  # the tiny profile's 4 check runs
)
TOWN = "roundabout_town-clear_noon-noise0.0"


def compose_in(root: Path, stage: str, *overrides: str):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(stage, overrides=[f"paths.root={root}", "profile=tiny", "progress=false", *overrides])


def sweep_cell(location: str, weather: str, noise: float, high: float, method: str = "mcd") -> SafetyCell:
    """A swept cell whose interval ends at ``high`` (the rest: what the sampler never reads)."""
    return SafetyCell(
        method=method, replicate=0, experiment="offline", location=location, weather=weather, noise=noise,
        estimate=Estimate(high / 2, 0.0, high, 4, 0.3, 0.05, "clopper_pearson", True),
        base_seed=100000, family_size=1, fixed_rollouts=4, rollouts=4, steps=100, seconds=1.0, collision_rate=0.0,
        off_road_rate=0.0, left_corridor_rate=0.0, reached_goal_rate=1.0, max_corridor_use=0.5,
        mean_corridor_use=0.5, mean_lateral_deviation=0.1, mean_eta2=None, mean_mutual_information=0.1,
        outcomes="1111", config_hash="x",
    )  # fmt: skip


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """Synthetic training frames, the behaviour-cloned MCD controller trained on them (one tiny epoch), and a sweep
    that flagged it in rain with noise at the 20 m ring only."""
    root = tmp_path_factory.mktemp("acquire")
    write_processed(root / "data/processed/offline/train.parquet", 160, seed=1, scenario="roundabout")
    write_processed(root / "data/processed/offline/val.parquet", 64, seed=2, scenario="roundabout")
    run_train(compose_in(root, "train", "experiment=offline", "outputs=pipeline", *ALL_TENTHS, "train.mcd.epochs=1"))
    swept = [o for o in TINY if not o.startswith("acquire.")]
    run_safety(compose_in(root, "safety", *swept))  # the sweep's cell at the training condition, really driven
    for cell in (
        sweep_cell("roundabout", "rain", 0.1, 0.95),  # above the target: not flagged
        sweep_cell("roundabout_large", "rain", 0.1, 0.23),  # flagged
        sweep_cell("roundabout_large", "rain", 0.1, 0.1, method="vi"),  # another controller's
    ):
        write_record(root / f"metrics/safety/{cell.name}.json", cell)
    return root


@pytest.fixture(scope="module")
def one_round(project):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        overrides = [f"paths.root={project}", "profile=tiny", "progress=false", *TINY, "acquire.rounds=1"]
        return run_acquire(compose("acquire", overrides=overrides), overrides)


def test_the_sampler_acquires_at_the_flagged_conditions_and_the_training_one_only():
    rng = np.random.default_rng(0)
    for _ in range(200):
        highs = rng.random(6)
        target = float(rng.random())
        cells = [sweep_cell(f"l{i}", "rain", 0.1 * (i % 2), float(h)) for i, h in enumerate(highs)]
        chosen = [w.label for w in targeted_conditions(TRAINING, flagged_cells(cells, target))]
        expected = [TRAINING.label] + [c.name.removeprefix("mcd-seed0-") for c in cells if c.estimate.high < target]
        assert chosen == expected


def test_the_stage_acquires_where_the_sweep_flagged_this_controller(one_round):
    assert one_round.flagged == ["roundabout_large-rain-noise0.1"]
    acquired = one_round.rounds[1].acquired
    assert [a.condition for a in acquired] == ["roundabout-clear_noon-noise0.0", "roundabout_large-rain-noise0.1"]
    assert all(a.frames > 0 and a.episodes == 1 for a in acquired)
    assert one_round.rounds[1].frames_added == sum(a.frames for a in acquired)
    assert one_round.rounds[1].train_frames == 160 + one_round.rounds[1].frames_added
    rows = {(c.round, c.cell) for c in one_round.checks}
    assert rows == {(r, cell) for r in (0, 1) for cell in [*(a.condition for a in acquired), TOWN]}
    for c in one_round.checks:
        assert c.low <= c.eta1 <= c.high and c.expert_low <= c.expert <= c.expert_high and c.n == 4


def test_each_round_is_compared_with_behaviour_cloning_on_the_shared_seeds(one_round):
    first = {c.cell: c.outcomes for c in one_round.checks if c.round == 0}
    compared = {b.cell: b for b in one_round.before_after}
    assert set(compared) == set(first) and all(b.round == 1 and b.level == 0.05 / 4 for b in compared.values())
    # the training cell's non-inferiority, one round: counted in the family of 3 + 1; 4 pairs bound nothing
    assert one_round.training == TRAINING.label and one_round.margin == 0.1
    assert {b.cell: b.non_inferior for b in compared.values()} == {
        cell: "undecided" if cell == TRAINING.label else "" for cell in first
    }
    for c in (c for c in one_round.checks if c.round == 1):
        assert len(c.outcomes) == c.n == len(first[c.cell])
        gain = (c.outcomes.count("1") - first[c.cell].count("1")) / c.n
        assert compared[c.cell].gain == pytest.approx(gain) and compared[c.cell].low <= gain <= compared[c.cell].high


def check_row(round_: int, cell: str, outcomes: str) -> AcquisitionCheck:
    n = len(outcomes)
    eta1 = outcomes.count("1") / n
    return AcquisitionCheck("mcd", 0, round_, cell, eta1, 0.0, 1.0, n, 1.0, 0.0, 1.0, outcomes)


def test_before_after_is_the_exact_mcnemar_test_at_the_bonferroni_level():
    """14 pairs, all discordant one way: p = 2·0.5^14 ≤ 0.05/2; 6 one way: 2·0.5^6 = 0.031 > 0.025 is undecided; the
    direction is the gain's; its false-verdict rate, summed exactly over every null table of 14 pairs, ≤ the level."""
    checks = [check_row(0, "a", "0" * 14), check_row(1, "a", "1" * 14)]
    checks += [check_row(0, "b", "1" * 6 + "0" * 8), check_row(1, "b", "0" * 14)]
    (a, b) = before_after(checks, training="elsewhere", margin=0.1)
    assert (a.verdict, b.verdict) == ("safer", "undecided") and a.p_value == pytest.approx(2 * 0.5**14)
    assert a.non_inferior == b.non_inferior == ""
    assert b.p_value == pytest.approx(2 * 0.5**6) and a.level == 0.025
    for concordant in range(15):  # under H0 the discordant pairs split as fair coins, whatever the concordant ones
        m = 14 - concordant
        error = 0.0
        for k in range(m + 1):
            after = "1" * k + "0" * (m - k) + "1" * concordant
            before = "0" * k + "1" * (m - k) + "1" * concordant
            pair = [check_row(0, "c", before), check_row(1, "c", after)]
            verdict = before_after(pair, training="elsewhere", margin=0.1, alpha=0.05)[0].verdict
            error += math.comb(m, k) * 0.5**m * (verdict != "undecided")
        assert error <= 0.05


def test_the_training_cell_is_non_inferior_only_where_its_pairs_bound_the_loss_within_the_margin():
    """400 pairs at the training cell, 2 lost and 1 gained: the gain's lower end lies above −0.05, declared
    non-inferior (counted in the family: level α/2); the same shares on 14 pairs are undecided."""
    before, after = "1" * 398 + "10", "1" * 398 + "01"
    (held,) = before_after([check_row(0, "t", before), check_row(1, "t", after)], training="t", margin=0.05)
    assert held.non_inferior == "non-inferior" and held.level == 0.025 and -0.05 < held.low <= held.gain == 0.0
    (short,) = before_after([check_row(0, "t", "1" * 14), check_row(1, "t", "1" * 14)], "t", 0.05)
    assert short.non_inferior == "undecided"


def test_compared_rounds_are_checked_on_fresh_seeds_and_a_lone_round_zero_reads_the_sweep(project, one_round, tmp_path):
    """The sweep flagged its cells by their outcomes on its own seeds: with rounds to compare, round 0 and every round
    drive acquire.check_seed's block instead. With no rounds (nothing compared) the behaviour-cloned controller at the
    training condition is the sweep's cell (same model, world, estimator, seeds): read back, not driven again."""
    for k in (0, 1):
        folder = project / f"data/acquire/offline/mcd-seed0/round{k}/check"
        cells = [read_record(SafetyCell, p, "acquire") for p in sorted(folder.glob("*.json"))]
        assert [c.location for c in cells] == ["roundabout", "roundabout_large", "roundabout_town"]
        assert {c.base_seed for c in cells} == {700000}
    swept = read_record(SafetyCell, project / "metrics/safety/mcd-seed0-roundabout-clear_noon-noise0.0.json", "safety")
    assert swept.base_seed == 100000
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        overrides = [f"paths.root={project}", "profile=tiny", "progress=false", *TINY, "acquire.rounds=0"]
        overrides += [f"acquire.out_dir={tmp_path}", f"acquire.out={tmp_path}/a.json"]
        overrides += [f"acquire.expert_logs={tmp_path}"]
        alone = run_acquire(compose("acquire", overrides=overrides), overrides)
    row = next(c for c in alone.checks if c.cell == TRAINING.label)
    assert (row.eta1, row.low, row.high, row.n, row.outcomes) == (
        swept.estimate.value, swept.estimate.low, swept.estimate.high, swept.estimate.n, swept.outcomes
    )  # fmt: skip
    # and the further check cells (the town) are not driven: nothing would be compared with them
    assert sorted(p.name for p in (tmp_path / "round0/check").glob("*.json")) == ["roundabout_large-rain-noise0.1.json"]


def test_the_check_cells_run_as_many_pairs_as_check_theta_asks_and_the_rounds_do_not_depend_on_it(project, tmp_path):
    """acquire.check_theta sizes every round's check cells (round 0's too); it and the check seeds are the checks'
    own: changing them rechecks finished rounds instead of running them again."""
    base = [f"paths.root={project}", "profile=tiny", "progress=false", *TINY, "acquire.rounds=1"]
    base += [f"acquire.out_dir={tmp_path}", f"acquire.out={tmp_path}/a.json", f"acquire.expert_logs={tmp_path}"]
    model = project / "models/offline/mcd/seed0.pt"
    keys = {
        more: rounds_key(compose_in(project, "acquire", *base[3:], *more), model)
        for more in ((), ("acquire.check_theta=0.6",), ("acquire.check_seed=1",), ("acquire.beta=0.3",))
    }
    assert len(set(keys.values())) == 2 and keys[("acquire.beta=0.3",)] != keys[()]
    overrides = [*base, "acquire.check_theta=0.6"]
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        larger = run_acquire(compose("acquire", overrides=overrides), overrides)
    assert {c.n for c in larger.checks} == {chernoff_n(0.6, 0.05)} != {4}  # tiny's scheme at that θ, every round
    assert {len(c.outcomes) for c in larger.checks} == {chernoff_n(0.6, 0.05)}


def test_the_default_checks_can_show_a_training_condition_that_stays_safe_non_inferior(tmp_path):
    """conf/acquire.yaml's check_theta at the quick profile: a cell of 12 flagged or further checks plus the training
    one (13 tests, Bonferroni) where every pair stays safe is declared non-inferior within the margin; 14 (the
    sweep's own size) could not."""
    stage = validate(AcquireStage, compose_in(tmp_path, "acquire", "profile=quick"))
    n = clopper_pearson_n(stage.acquire.check_theta, stage.safety.gamma)
    assert stage.safety.scheme == "clopper_pearson" and n == 75
    level = 0.05 / 13
    assert non_inferior(paired_table([True] * n, [True] * n), stage.acquire.margin, level)
    assert not non_inferior(paired_table([True] * 14, [True] * 14), stage.acquire.margin, level)


def test_the_controller_the_rounds_end_with_is_copied_where_later_stages_find_it(project, one_round, tmp_path):
    """acquire.out_dir/controller.pt: the last round's controller (no rounds: the behaviour-cloned one), at a path
    the warnings' rerun (conf/gym_avoid_acquired.yaml) names whatever the round count."""
    folder = project / "data/acquire/offline/mcd-seed0"
    assert (folder / "controller.pt").read_bytes() == (folder / "round1/models/mcd/seed0.pt").read_bytes()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        overrides = [f"paths.root={project}", "profile=tiny", "progress=false", *TINY, "acquire.rounds=0"]
        overrides += [f"acquire.out_dir={tmp_path}", f"acquire.out={tmp_path}/a.json"]
        overrides += [f"acquire.expert_logs={tmp_path}"]
        run_acquire(compose("acquire", overrides=overrides), overrides)
    assert (tmp_path / "controller.pt").read_bytes() == (project / "models/offline/mcd/seed0.pt").read_bytes()
    avoid = compose_in(project, "gym_avoid_acquired", "gym_world=highway_roundabout", "experiment=offline")
    assert avoid.avoid.model_path == str(folder / "controller.pt")


def test_every_acquired_label_is_the_experts_command_in_that_state(project, one_round):
    """The autopilot's command recomputed from each row's recorded pose and speed on its scenario's route: the
    label is the expert's in the state the learner reached, whoever drove the step."""
    table = pq.read_table(project / "data/acquire/offline/mcd-seed0/round1/acquired.parquet").to_pydict()
    learner_steps = 0
    for scenario in set(table["scenario"]):
        world = validate(SafetyStage, compose_in(project, "safety", *TINY[:3], f"scenario={scenario}"))
        route = build_geometry(world.scenario).route
        for i in [i for i, s in enumerate(table["scenario"]) if s == scenario]:
            expert = Autopilot(route, world.vehicle, AutopilotConfig(), world.control_hz, seed=table["seed"][i])
            state = {key: float(table[key][i]) for key in ("x", "y", "yaw", "speed")}
            assert math.isclose(expert.act(state).label, table["steering"][i], abs_tol=1e-4), (scenario, i)
            learner_steps += table["applied_steering"][i] != table["steering"][i]
    assert learner_steps > 0  # the learner drove some steps: the states are its own


def test_a_round_is_deterministic(project, one_round):
    again = project / "again"
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        overrides = [f"paths.root={project}", "profile=tiny", "progress=false", *TINY, "acquire.rounds=1"]
        overrides += [f"acquire.out_dir={again}", f"acquire.out={again}/acquisition.json"]
        second = run_acquire(compose("acquire", overrides=overrides), overrides)
    first_dir = project / "data/acquire/offline/mcd-seed0/round1"
    assert pq.read_table(first_dir / "acquired.parquet").equals(pq.read_table(again / "round1/acquired.parquet"))
    first_state = read_checkpoint(first_dir / "models/mcd/seed0.pt")["state"]
    second_state = read_checkpoint(again / "round1/models/mcd/seed0.pt")["state"]
    assert all(torch.equal(first_state[k], second_state[k]) for k in first_state)
    assert [dataclasses.asdict(c) for c in second.checks] == [dataclasses.asdict(c) for c in one_round.checks]


def test_retraining_without_acquired_frames_is_behaviour_cloning_bit_for_bit(project, tmp_path):
    """Aggregation with nothing acquired and the retraining of a round reproduce the train stage's controller."""
    processed = project / "data/processed/offline"
    frames = aggregate(RAW_SCHEMA.empty_table(), processed, tmp_path / "processed", SteeringBins())
    assert frames == 160
    assert pq.read_table(tmp_path / "processed/train.parquet").equals(pq.read_table(processed / "train.parquet"))
    overrides = [f"paths.root={project}", "profile=tiny", "progress=false", "experiment=offline", *ALL_TENTHS]
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        path, _ = retrain([*overrides, "train.mcd.epochs=1"], "mcd", tmp_path / "processed", tmp_path / "models")
    cloned = read_checkpoint(project / "models/offline/mcd/seed0.pt")["state"]
    retrained = read_checkpoint(path)["state"]
    assert cloned.keys() == retrained.keys()
    assert all(torch.equal(cloned[k], retrained[k]) for k in cloned)


def test_no_sweep_cells_is_one_line_naming_the_key_before_any_work(tmp_path):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose("acquire", overrides=[f"paths.root={tmp_path}", "profile=tiny", "outputs=pipeline"])
        with pytest.raises(ConfigError, match=r"^acquire.cells_dir=.*no safety cell of offline mcd seed0"):
            run_acquire(cfg, [])
    assert not any(tmp_path.iterdir())


def test_a_condition_outside_the_world_is_one_line_naming_the_key(tmp_path):
    training = "acquire.training={location: roundabout, weather: env, noise: 0.0}"
    cfg = compose_in(tmp_path, "acquire", training)
    with pytest.raises(ConfigError, match=r"^acquire.training.weather='env' must name a weather"):
        run_acquire(cfg, [])


def test_each_round_is_an_mlflow_run_with_its_sizes_and_check_cells(project, one_round):
    from mlflow.tracking import MlflowClient

    from uqdrive.tracking import store_uris

    client = MlflowClient(store_uris(project)[0])
    experiment = client.get_experiment_by_name("uqdrive/acquire")
    runs = {r.info.run_name.split(" · ")[-1]: r.data.metrics for r in client.search_runs([experiment.experiment_id])}
    last = runs["offline-mcd-seed0 round 1"]
    assert last["frames_added"] == one_round.rounds[1].frames_added
    assert last["val_accuracy"] == one_round.rounds[1].val_accuracy
    flagged = next(c for c in one_round.checks if (c.round, c.cell) == (1, "roundabout_large-rain-noise0.1"))
    assert (last["eta1/roundabout_large-rain-noise0.1"], last["eta1_high/roundabout_large-rain-noise0.1"]) == (
        flagged.eta1,
        flagged.high,
    )
    assert "offline-mcd-seed0 round 0" in runs


AXIS = (
    "acquire.world_axis={key: env_kwargs.config.other_vehicles_type, values: "
    "{idm: highway_env.vehicle.behavior.IDMVehicle, aggressive: highway_env.vehicle.behavior.AggressiveVehicle}}"
)


def test_a_gymnasium_worlds_flagged_location_is_placed_by_its_axis(tmp_path):
    """A sweep's Gymnasium cell is named <world>-<label>: the acquisition drives the world at that label's value, as
    the sweep's cell did; a location the axis does not name is one line naming the key."""
    gym = ("gym_world=highway_roundabout", "experiment=highway_roundabout", "safety.speed=8.0", AXIS)
    gym += ("acquire.checks=[]",)  # conf/acquire.yaml's town checks are the pybullet world's
    training = "acquire.training={location: highway_roundabout-idm, weather: env, noise: 0.0}"
    stage = validate(AcquireStage, compose_in(tmp_path, "acquire", *gym, training))
    assert placed(stage, Where("highway_roundabout-aggressive", "env", 0.1)) == {
        "++gym_world.env_kwargs.config.other_vehicles_type": "highway_env.vehicle.behavior.AggressiveVehicle",
        "gym_world.name": "highway_roundabout-aggressive",
        "noise": 0.1,
    }
    shutil.copy(CONF.parent / "params.yaml", tmp_path / "params.yaml")  # its axis: idm first, as collected
    world = ("gym_world=highway_roundabout", "experiment=highway_roundabout")
    collected = validate(AcquireStage, compose_in(tmp_path, "gym_acquire", *world))
    assert collected.acquire.cells_dir == f"{tmp_path}/metrics/highway_roundabout/safety"
    swept = as_swept(collected, collected.acquire.training)  # the world as collected: the axis' first location
    assert (swept.location, swept.weather, swept.noise) == ("highway_roundabout-idm", "env", 0.0)
    assert (
        as_swept(stage, Where("highway_roundabout-aggressive", "env", 0.0)).location == "highway_roundabout-aggressive"
    )
    wrong = "acquire.training={location: highway_roundabout-defensive, weather: env, noise: 0.0}"
    with pytest.raises(ConfigError, match=r"^acquire.training.location='highway_roundabout-defensive' must be"):
        validate(AcquireStage, compose_in(tmp_path, "acquire", *gym, wrong))
    town = "acquire.checks=[{location: roundabout_town, weather: clear_noon, noise: 0.0}]"  # conf/acquire.yaml's
    with pytest.raises(ConfigError, match=r"^acquire.checks\[0\].weather='clear_noon' must be 'env'"):
        validate(AcquireStage, compose_in(tmp_path, "acquire", *gym, training, town))
