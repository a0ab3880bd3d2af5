"""The `avoid` stage on the tiny profile: cells per condition, calibration, reuse, outputs, MLflow runs, the
summary, clear errors."""

import json

import pytest
import torch
from mlflow.tracking import MlflowClient
from scipy import stats
from user_policy_kit import linear_module, save_torchscript, write_yaml

import uqdrive.safety.runner as runner
from uqdrive.avoid.plan import KNOWN, build_settings
from uqdrive.avoid.results import Mode
from uqdrive.pipeline.avoid_stage import run_avoid
from uqdrive.pipeline.avoid_summary_stage import run_avoid_summary
from uqdrive.policy.warnings import WarningController
from uqdrive.records import as_dict
from uqdrive.schema import ConfigError
from uqdrive.tracking import store_uris


@pytest.mark.slow
def test_stage_writes_every_cell_logs_one_run_per_cell_reuses_cells_and_summarises(
    avoid_config, stage_config, tmp_path
):
    result = run_avoid(avoid_config("model=mcd"))
    saved = json.loads((tmp_path / "metrics/avoid/mcd-seed0.json").read_text())
    assert saved == as_dict(result) and saved["samples_per_frame"] == 21  # chernoff_n(0.3, 0.05), the tiny profile
    assert saved["conditions"] == [KNOWN, "fog"]  # the tiny profile's one unknown condition
    for condition in saved["conditions"]:
        for mode in Mode:
            cell = saved["cells"][condition][mode]
            # every condition gets exactly the scheme's runs: chernoff_n(0.7, 0.05) = 4, never a random share
            assert cell["n"] == 4 and cell["scheme"] == "chernoff" and cell["guaranteed"] and not cell["reused"]
            assert cell["eta1_low"] <= cell["eta1"] <= cell["eta1_high"]
            assert cell["autonomy"] == 1 - cell["handover_rate"] and 0 <= cell["full_speed_fraction"] <= 1
            assert sum(cell["terminations"].values()) == 4
            assert 0 <= cell["timeout_before_obstacle_rate"] <= 1 - cell["eta1"] + 1e-12  # a timeout is never safe
            assert (tmp_path / f"cache/rollouts/avoid/mcd-seed0/mcd-seed0-{condition}-{mode}.jsonl").exists()
            assert (tmp_path / f"data/avoid/mcd-seed0/traces/mcd-seed0-{condition}-{mode}.npz").exists()
            assert (tmp_path / f"plots/avoid/mcd-seed0/cells/mcd-seed0-{condition}-{mode}.png").stat().st_size > 5000
            assert len(cell["outcomes"]) == 4 and cell["outcomes"].count("1") == round(cell["eta1"] * 4)
            failing = [i for i, outcome in enumerate(cell["outcomes"]) if outcome == "0"]  # each a failure record
            assert sorted(f["index"] for f in cell["failures"]) == failing
            assert all(f["seed"] == cell["base_seed"] + f["index"] for f in cell["failures"])
            assert {f["segment"] for f in cell["failures"]} <= {"before the obstacle", "past the obstacle"}
        for mode in ("off", "fresh_off"):  # warnings off: only counted
            assert saved["cells"][condition][mode]["handover_rate"] == 0
        # fresh_off and calibrated run the validation seeds, the others the stage's
        assert [saved["cells"][condition][m]["base_seed"] for m in Mode] == [200000, 200000, 300000, 300000]
    assert any(cell["failures"] for by_mode in saved["cells"].values() for cell in by_mode.values())
    for mode in Mode:  # one unknown condition: its mixture is that cell
        assert saved["unknown"][mode]["eta1"] == saved["cells"]["fog"][mode]["eta1"]
    assert saved["cells"][KNOWN]["on"]["thresholds"] == {"delta1": 0.7, "delta2": 0.6, "tau": 0.45}
    calibration = saved["calibration"]["certificate"]
    assert saved["cells"][KNOWN]["calibrated"]["thresholds"] == {k: calibration[k] for k in ("delta1", "delta2", "tau")}
    # Learn-then-Test on the 4 known runs: with no hand-over in any, the null "hand-over rate > 0.7" has
    # p = 0.3^4 = 0.008 <= 0.05, so the never-firing candidate (first in the sequence) at least is certified
    assert calibration["feasible"] and calibration["certified"] >= 1 and calibration["replayed"]["certified"]
    assert calibration["guarantee"].startswith("With probability ≥ 0.95, each of the")
    assert calibration["calibration_runs"] == {KNOWN: 4, "fog": 4} and calibration["learn_runs"] == {KNOWN: 0, "fog": 0}
    calibrated = saved["cells"][KNOWN]["calibrated"]
    autonomous = round(calibrated["autonomy"] * 4)  # of the cell's 4 fixed runs
    p_value = sum(stats.binom.pmf(k, 4, 0.3) for k in range(autonomous, 5))  # P(Bin(4, target) >= autonomous)
    check = saved["calibration"]["fresh_seed_check"]
    assert check == {
        "check": {
            "runs": 4,
            "autonomous": autonomous,
            "target": 0.3,
            "level": 0.025,  # γ over the tiny profile's 2 controllers: 4 fresh runs give power 0.8 at autonomy 0.95
            "p_value": pytest.approx(p_value),
            "target_met": p_value <= 0.025,
        },
        "known_autonomy": calibrated["autonomy"],
        "known_eta1": calibrated["eta1"],
        "unknown_eta1": saved["unknown"]["calibrated"]["eta1"],
        "base_seed": 300000,
    }
    rule = calibration["rule"]  # the deployed rule: the calibrated thresholds, the tier rule with its exact error
    assert (rule["delta1"], rule["delta2"], rule["tau"]) == (
        calibration["delta1"],
        calibration["delta2"],
        calibration["tau"],
    )
    assert 0 <= rule["tier"]["wrong_tier_error"] <= rule["tier"]["gamma"]
    assert calibration["middle_guaranteed"] == rule["tier"]["middle_guaranteed"]
    assert calibration["candidates"] > 100 and set(saved["calibration"]["replay_check"]) == {KNOWN, "fog"}
    rows = (tmp_path / "plots/avoid/mcd-seed0/tradeoff.csv").read_text().splitlines()
    assert len(rows) == calibration["candidates"] + 1 and rows[0].startswith("delta1,delta2,tau")
    for name in ("trajectories", "warnings", "tradeoff"):
        assert (tmp_path / f"plots/avoid/mcd-seed0/{name}.png").stat().st_size > 5000

    client = MlflowClient(store_uris(tmp_path)[0])
    runs = client.search_runs([client.get_experiment_by_name("uqdrive/avoid").experiment_id])
    by_name = {r.info.run_name.split(" · η1=")[0]: r for r in runs}  # condition first, the η̂1 last
    cells = {f"adhoc · {c} {m} · mcd seed0" for c in (KNOWN, "fog") for m in Mode}
    assert set(by_name) == cells | {"adhoc · calibration · mcd seed0"}
    run = by_name["adhoc · fog on · mcd seed0"]
    params = run.data.params
    assert {
        k: params[k] for k in ("method", "condition", "warnings", "delta1", "samples_per_frame", "n", "cell_theta")
    } == {
        "method": "mcd",
        "cell_theta": "0.7",
        "condition": "fog",
        "warnings": "on",
        "delta1": "0.7",
        "samples_per_frame": "21",
        "n": "4",
    }
    assert "avoid.theta" not in params and run.data.tags["reused"] == "false"  # each key once
    assert run.data.metrics["eta1"] == pytest.approx(saved["cells"]["fog"]["on"]["eta1"])
    assert {a.path for a in client.list_artifacts(run.info.run_id)} == {"paths.png", "rollouts.csv"}  # every cell's
    assert run.data.tags["cell"] == "mcd-seed0-fog-on"

    again = run_avoid(avoid_config("model=mcd"))  # every cell is reused, with the same numbers
    assert all(again.cells[c][m].reused for c in again.conditions for m in Mode)
    assert {c: {m: again.cells[c][m].estimate.value for m in Mode} for c in again.conditions} == {
        c: {m: saved["cells"][c][m]["eta1"] for m in Mode} for c in saved["conditions"]
    }

    run_avoid(avoid_config("model=mcd", "seed=1"))  # a second replicate (here the same network: plumbing)
    summary = run_avoid_summary(stage_config("avoid_summary", "methods=[mcd]", "replicates=[0,1]"))
    assert json.loads((tmp_path / "metrics/avoid.json").read_text()) == as_dict(summary)
    on = summary.answer("mcd", "unknown mixture", "on")
    second = json.loads((tmp_path / "metrics/avoid/mcd-seed1.json").read_text())
    assert on.replicates == [0, 1] and on.estimates == [saved["unknown"]["on"]["eta1"], second["unknown"]["on"]["eta1"]]
    assert on.low <= on.value <= on.high and on.value == pytest.approx(sum(on.estimates) / 2)
    assert summary.paper.avoid.unknown_on == 0.9
    assert (tmp_path / "plots/avoid/summary/coll_avoid_main.png").stat().st_size > 5000
    with pytest.raises(FileNotFoundError, match="vi-seed0.json is missing; .* dvc repro avoid@vi-0"):
        run_avoid_summary(stage_config("avoid_summary", "methods=[vi]", "replicates=[0]"))


def test_thresholds_actions_and_samples_come_from_config(avoid_config):
    settings = build_settings(
        avoid_config(
            "model=vi",
            "warning.delta1=0.8",
            "warning.tau=0.3",
            "warning.actions.warning0.speed=0.25",
            "warning.theta=0.2",
            "avoid.horizon_s=10",
        )
    )
    w = settings.rule.config
    assert (w.delta1, w.delta2, w.tau, w.actions[0].speed, w.samples) == (0.8, 0.6, 0.3, 0.25, 47)
    policy = settings.job(settings.known, settings.rule, 0).policy.build(15.0)
    assert isinstance(policy, WarningController) and policy.rule is settings.rule and policy.n_samples == 47
    assert settings.job(settings.known, None, 0).policy.build(15.0).n_samples == 47  # warnings off: same draws


@pytest.mark.parametrize(
    ("overrides", "error", "match"),
    [
        (("warning.delta2=0.8",), ValueError, r"warning.delta2=0.8 must be <= delta1=0.7"),
        (("warning.delta1=1.5",), ValueError, r"warning.delta1=1.5: input should be less than or equal to 1"),
        (("warning.delta2=-0.2",), ValueError, r"warning.delta2=-0.2: input should be greater than or equal to 0"),
        (("warning.tau=-1",), ValueError, r"warning.tau=-1: input should be greater than or equal to 0"),
        (("warning.actions.warning2.speed=0.5",), ValueError, r"warning.actions.warning2.speed=0.5 must be 0 when"),
        (("model.name=lasso",), ValueError, r"model.name='lasso' does not match model._target_ VIPosterior"),
        (
            ("avoid.model_path=/nonexistent/vi.pt",),
            ValueError,
            r"^avoid.model_path=/nonexistent/vi.pt does not exist; train it first: dvc repro train@avoid-vi$",
        ),
        (("avoid.theta=0",), ValueError, r"avoid.theta=0: input should be greater than 0"),
        (
            ("avoid.scheme=bootstrap",),
            ValueError,
            r"avoid.scheme='bootstrap': input should be 'chernoff'",
        ),
        (("avoid.speed=0",), ValueError, r"avoid.speed=0: input should be greater than 0"),
        (("avoid.speed=25",), ValueError, r"avoid.speed=25.0 must be <= vehicle.max_speed=20.0"),
        (("avoid.eps=0",), ValueError, r"avoid.eps=0: input should be greater than 0"),
        (("avoid.horizon_s=-1",), ValueError, r"avoid.horizon_s=-1: input should be greater than 0"),
        (
            ("avoid.horizon_s=2",),
            ValueError,
            r"avoid.horizon_s=2 is too short: a run slowed to 8 m/s needs 3\.\d s to pass the obstacle \(\d+ m\); "
            r"set at least 4",
        ),
        (("warning.actions.warning1.speed=0",), ValueError, r"a slow-down to speed 0 without a hand-over never passes"),
        (("avoid.unknown=[]",), ValueError, r"avoid.unknown=\[\]: tuple should have at least 1 item"),
        (("avoid.unknown=[{name:known}]",), ValueError, r"avoid.unknown\[0\].name='known' is the training condition"),
        (
            ("avoid.unknown=[{name:snow,weather:snow}]",),
            ValueError,
            r"avoid.unknown\[0\].weather='snow' is not loaded; .* add \+weather@weathers.snow=snow",
        ),
        (
            ("avoid.unknown=[{name:x,noise:-1}]",),
            ValueError,
            r"avoid.unknown\[0\].noise=-1: input should be greater",
        ),
        (
            ("avoid.unknown=[{name:x,scenario:{obstacle_colour:[1,1,1]}}]",),
            ValueError,
            r"avoid.unknown\[0\].scenario.obstacle_colour: unknown key; did you mean 'obstacle_color'\?",
        ),
        (
            ("avoid.calibration.autonomy_target=1",),
            ValueError,
            r"avoid.calibration.autonomy_target=1: input should be less than 1",
        ),
        (
            ("avoid.calibration.autonomy_target=0.5",),
            ValueError,
            r"autonomy_target=0.5 cannot be certified with 4 known-condition runs \(it needs 5\)",
        ),
        (
            ("avoid.calibration.deltas=[0.5,1.5]",),
            ValueError,
            r"avoid.calibration.deltas\[1\]=1.5: input should be less",
        ),
        (("executor.workers=0",), ValueError, r"executor.workers=0: input should be greater than or equal to 1"),
        (("scenario=roundabout",), ValueError, r"scenario.kind='roundabout' must be 'obstacle' for the avoid stage"),
        (
            ("avoid.calibration.order=learned",),
            ValueError,
            r"^avoid.calibration.order='learned' needs avoid.calibration.calibration_fraction < 1$",
        ),
    ],
)
def test_bad_input_fails_before_any_rollout(avoid_config, tmp_path, monkeypatch, overrides, error, match):
    def no_rollouts(*args, **kwargs):
        raise AssertionError("rollouts started")

    monkeypatch.setattr(runner, "make_executor", no_rollouts)
    with pytest.raises(error, match=match):
        run_avoid(avoid_config("model=vi", *overrides))
    assert not (tmp_path / "metrics").exists() and not (tmp_path / "mlflow.db").exists()


def test_warnings_on_and_off_and_thresholds_at_0_or_1_share_the_configured_draws(avoid_config):
    """The calibration may choose a never- or always-warning candidate: its tier rule decides 0 and 1 too, so every
    cell, with warnings or without, takes the configured sequential draws and only the warnings differ."""
    settings = build_settings(avoid_config("model=vi"))
    assert settings.spec.draws.scheme == "sequential"
    assert (
        settings.job(settings.known, None, 0).policy.draws
        == settings.job(settings.known, settings.rule, 0).policy.draws
    )
    for delta1, delta2 in ((0.0, 0.0), (1.0, 0.6), (1.0, 1.0)):
        edge = settings.rule.with_thresholds(delta1, delta2, 0.45)
        policy = settings.job(settings.known, edge, 0).policy
        assert policy.draws.scheme == "sequential" and isinstance(policy.build(15.0), WarningController)


def dropout_policy(folder, draws: int):
    """A user's Bayesian policy: a torch module with dropout kept on, ``draws`` passes a frame (its YAML)."""
    torch.manual_seed(0)
    module = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Dropout(0.5), torch.nn.Linear(48 * 64, 21))
    save_torchscript(module, folder / "dropout.pt")
    return write_yaml(folder / f"dropout{draws}.yaml", f"file: dropout.pt\nmc_draws: {draws}\n")


@pytest.mark.slow
def test_a_users_bayesian_policy_runs_the_stage_with_warnings_off_on_and_calibrated(avoid_config, tmp_path):
    """The avoid stage certifies a user's controller as it does uqdrive's: every cell on the policy's own draws (21 a
    frame: the tiny profile's warning.samples), the thresholds calibrated on its warnings-off runs and deployed."""
    result = run_avoid(avoid_config("model=mcd", f"avoid.policy={dropout_policy(tmp_path, 21)}"))
    saved = json.loads((tmp_path / "metrics/avoid/dropout21-seed0.json").read_text())
    assert saved == as_dict(result) and result.method == "dropout21" and result.samples_per_frame == 21
    for condition in result.conditions:
        for mode in Mode:
            cell = result.cell(condition, mode)
            assert cell.estimate.n == 4 and 0 <= cell.estimate.low <= cell.estimate.value <= cell.estimate.high <= 1
        assert result.cell(condition, Mode.OFF).handover_rate == 0
    assert sum(result.cell(c, Mode.OFF).warning2_runs for c in result.conditions) > 0  # counted on its draws
    certificate = result.calibration.certificate
    assert certificate.calibration_runs == {KNOWN: 4, "fog": 4} and certificate.candidates > 100
    assert certificate.rule.tier.scheme == "fixed" and certificate.rule.tier.looks == [21]
    calibrated = result.cell(KNOWN, Mode.CALIBRATED).thresholds
    assert calibrated == {k: getattr(certificate, k) for k in ("delta1", "delta2", "tau")}
    assert set(result.calibration.replay_check) == {KNOWN, "fog"}


@pytest.mark.parametrize(
    ("draws", "match"),
    [
        (0, r"^avoid.policy=.*plain.yaml: the avoid stage needs a policy that gives draws \(Action.draws: its "),
        (8, r"^avoid.policy=.*dropout8.yaml: .*dropout.pt gives 8 draws a frame; the warning rule reads 21 "),
    ],
)
def test_a_users_policy_without_the_rules_draws_is_refused_in_one_line_before_any_rollout(
    avoid_config, tmp_path, monkeypatch, draws, match
):
    if draws:
        path = dropout_policy(tmp_path, draws)
    else:
        save_torchscript(linear_module(), tmp_path / "plain.pt")
        path = write_yaml(tmp_path / "plain.yaml", "file: plain.pt\n")
    monkeypatch.setattr(runner, "make_executor", lambda *args, **kwargs: pytest.fail("rollouts started"))
    with pytest.raises(ConfigError, match=match):
        run_avoid(avoid_config("model=mcd", f"avoid.policy={path}"))
    assert not (tmp_path / "metrics").exists()
