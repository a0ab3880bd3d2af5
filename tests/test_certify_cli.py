"""`uqdrive certify` as a CI gate: exit 0 only when "η1 ≥ target" is certified (a lane keeper), 1 when refuted (a
constant hard steer), 3 when undecided within the budget; the record and the MLflow run say the same; a rerun
replays its attempt (the ledger), an edited policy is a new attempt on fresh seeds at γ_2; with fixed seeds the
rollouts are reused across the test's settings; a budget below the floor, an existing --out, a corrupt ledger:
exit 2 before any rollout. The sequential test it runs errs at most γ at every true η1: its
rule read through `decide` and the error computed exactly by the independent dynamic program of
tests/test_uq_threshold.py, over a fine grid."""

from __future__ import annotations

import json
from pathlib import Path

import mlflow
import numpy as np
import pytest
from test_uq_threshold import assert_guarantee, decisions, forward
from user_policy_kit import Constant, save_torchscript, write_package, write_yaml

from uqdrive.pipeline.certify_stage import CertifySection
from uqdrive.tools.cli import main
from uqdrive.tracking import store_uris

ROOT = Path(__file__).resolve().parents[1]

KEEPER = "policy:\n  _target_: h50_user_policies.policies.LaneKeeper\n"
HALF = """from uqdrive.policy.interface import Action
from h50_user_policies.policies import LaneKeeper


class HalfKeeper(LaneKeeper):
    def reset(self, seed):
        super().reset(seed)
        self.hard = seed % 2 == 1

    def act(self, frame, info):
        return Action(1.0) if self.hard else super().act(frame, info)
"""


def certify(tmp_path, policy, *args: str) -> tuple[int, dict]:
    out = tmp_path / "record.json"
    out.unlink(missing_ok=True)
    code = main(
        ["certify", "--policy", str(policy), "--out", str(out), "--out-dir", str(tmp_path), "--no-progress", *args]
    )
    return code, json.loads(out.read_text()) if out.exists() else {}


@pytest.mark.slow  # whole certify runs, MLflow included
def test_certify_exits_0_for_a_safe_policy_and_1_for_one_that_steers_off_the_road(tmp_path, monkeypatch, capsys):
    write_package(tmp_path / "site", monkeypatch)
    keeper = write_yaml(tmp_path / "keeper.yaml", KEEPER)
    code, record = certify(tmp_path, keeper, "--eta", "0.9")
    assert code == 0 and record["verdict"] == "certified" and record["safe"] == record["rollouts"] <= 64
    assert 0.9 <= record["eta1_low"] < record["eta1_high"] == 1.0 and record["policy_kind"] == "class"
    assert record["off_road_rate"] == 0 and record["mean_eta2"] is None and record["warning_share"] is None
    assert record["attempt"] == 1 and record["interval_gamma"] == record["attempt_gamma"] < 0.61 * 0.05
    line = capsys.readouterr().out.strip()
    assert line.startswith("CERTIFIED: eta1 >= 0.9: a policy with eta1 < 0.9 passes with probability <= 0.0304. ")
    assert f"{record['rollouts']}/{record['rollouts']} rollouts safe" in line and "attempt 1 of this policy" in line

    hard = save_torchscript(Constant(1.0), tmp_path / "hard_left.pt")
    code, record = certify(tmp_path, hard, "--eta", "0.9")
    assert code == 1 and record["verdict"] == "refuted" and record["safe"] == 0 and record["rollouts"] <= 8
    assert record["off_road_rate"] + record["collision_rate"] == 1  # each run read left the road or hit something
    assert capsys.readouterr().out.startswith("REFUTED: eta1 < 0.9: a policy with eta1 >= 0.9 is refuted with ")
    assert record["eta1_high"] < 0.9

    client = mlflow.MlflowClient(store_uris(tmp_path)[0])
    (experiment,) = [e for e in client.search_experiments() if e.name.endswith("/certify")]
    runs = client.search_runs([experiment.experiment_id])
    assert sorted(r.data.tags["verdict"] for r in runs) == ["certified", "refuted"]
    assert sorted(r.data.metrics["certified"] for r in runs) == [0.0, 1.0]
    assert all(r.data.tags["guarantee"].startswith(r.data.tags["verdict"].upper()) for r in runs)
    # each decided policy is a model version carrying its certificate; only the certified one has the alias
    passed = client.get_model_version_by_alias("keeper", "certified")
    assert passed.tags["verdict"] == "certified" and passed.tags["guarantee"].startswith("CERTIFIED: eta1 >= 0.9")
    (failed,) = client.search_model_versions("name='hard_left'")
    assert failed.tags["verdict"] == "refuted" and not failed.aliases
    assert [e.name for e in client.search_experiments()] == [experiment.name]  # no empty `Default` beside it


@pytest.mark.slow  # whole certify runs, MLflow included
def test_certify_exits_3_when_its_budget_does_not_decide(tmp_path, monkeypatch):
    """A policy safe on every other seed (a lane keeper that steers hard left on odd seeds): η1 = 0.5 exactly, so at
    target 0.5 the test neither certifies nor refutes within 8 rollouts (half of them safe)."""
    write_package(tmp_path / "site", monkeypatch)
    (tmp_path / "site" / "h50_half.py").write_text(HALF)
    half = write_yaml(tmp_path / "half.yaml", "policy:\n  _target_: h50_half.HalfKeeper\n")
    code, record = certify(tmp_path, half, "--eta", "0.5", "--gamma", "0.2", "--budget", "8", "--seed-base", "0")
    assert code == 3 and record["verdict"] == "undecided" and record["rollouts"] == 8 == 2 * record["safe"]
    assert record["eta1_low"] < 0.5 < record["eta1_high"]  # the interval of an undecided test holds the target


@pytest.mark.slow  # whole certify runs, MLflow included
def test_a_rerun_replays_its_attempt_and_an_edited_policy_is_a_new_attempt(tmp_path, monkeypatch):
    source = write_package(tmp_path / "site", monkeypatch)
    keeper = write_yaml(tmp_path / "keeper.yaml", KEEPER)
    args = ("--eta", "0.5", "--horizon", "20")
    first = certify(tmp_path, keeper, *args)[1]
    again = certify(tmp_path, keeper, *args)[1]
    assert not first["reused"] and again["reused"] and again["cell_key"] == first["cell_key"]
    assert first["attempt"] == again["attempt"] == 1 and again["base_seed"] == first["base_seed"] == 0
    source.write_text(source.read_text().replace("kp: float = 3.0", "kp: float = 3.5"))
    edited = certify(tmp_path, keeper, *args)[1]
    assert not edited["reused"] and edited["cell_key"] != first["cell_key"]
    assert edited["policy_digest"] != first["policy_digest"] and edited["attempt"] == 2
    assert edited["base_seed"] >= first["base_seed"] + 400 and edited["attempt_gamma"] == first["attempt_gamma"] / 4
    ledger = json.loads((tmp_path / "ledger.json").read_text())
    assert [a["verdict"] for a in ledger["policies"][first["policy"]]] == ["certified", "certified"]


@pytest.mark.slow  # whole certify runs
def test_fixed_seeds_reuse_the_rollouts_across_the_tests_settings(tmp_path, monkeypatch):
    """--seed-base: no ledger, the full γ; changing --eta, --gamma or --budget replays the logged rollouts and runs
    only those the new test reads beyond them."""
    write_package(tmp_path / "site", monkeypatch)
    keeper = write_yaml(tmp_path / "keeper.yaml", KEEPER)
    first = certify(tmp_path, keeper, "--eta", "0.5", "--seed-base", "7")[1]
    assert first["attempt"] == 0 and first["base_seed"] == 7 and first["attempt_gamma"] == 0.05
    for change in (("--eta", "0.4"), ("--eta", "0.5", "--gamma", "0.1"), ("--eta", "0.5", "--budget", "40")):
        again = certify(tmp_path, keeper, *change, "--seed-base", "7")[1]
        assert again["cell_key"] == first["cell_key"] and again["rollouts"] <= first["rollouts"] and again["reused"]
    higher = certify(tmp_path, keeper, "--eta", "0.8", "--seed-base", "7")[1]  # needs more: the log is extended
    assert higher["cell_key"] == first["cell_key"] and higher["rollouts"] > first["rollouts"] and not higher["reused"]
    assert higher["outcomes"].startswith(first["outcomes"])
    assert not (tmp_path / "ledger.json").exists()


def test_bad_gate_inputs_exit_2_before_any_rollout(tmp_path, capsys):
    """A budget below the zero-failure floor (naming one that can), an existing --out, a corrupt ledger, a ledger
    of another tool: one line, exit 2, the files left as they were."""
    policy = save_torchscript(Constant(0.0), tmp_path / "straight.pt")
    code = main(["certify", "--policy", str(policy), "--out-dir", str(tmp_path), "--eta", "0.99", "--gamma", "0.01"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("uqdrive certify: budget=400: can never certify eta1 >= 0.99 at gamma=0.006079")
    assert "--budget 620 can" in err and not list(tmp_path.glob("cache/rollouts/certify/*"))
    out = tmp_path / "mine.json"
    out.write_text("{}")
    assert main(["certify", "--policy", str(policy), "--out", str(out)]) == 2
    assert capsys.readouterr().err == f"uqdrive certify: --out={str(out)!r} exists; give another path, or --force " \
        "to overwrite it\n"  # fmt: skip
    for text, says in (("{not json", "Expecting property name"), ('{"format": "x"}', "not a 'uqdrive certify ledger'")):
        (tmp_path / "ledger.json").write_text(text)
        assert main(["certify", "--policy", str(policy), "--out-dir", str(tmp_path), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"uqdrive certify: ledger {tmp_path / 'ledger.json'}: ") and says in err
        assert err.count("\n") == 1 and (tmp_path / "ledger.json").read_text() == text and out.read_text() == "{}"


def test_a_bad_policy_file_exits_2_with_one_line(tmp_path, capsys):
    assert certify(tmp_path, tmp_path / "nope.onnx")[0] == 2
    err = capsys.readouterr().err
    assert err == f"uqdrive certify: {tmp_path / 'nope.onnx'}: no such file; expected a TorchScript (.pt, .ts), " \
        "ONNX (.onnx), stable-baselines3 (.zip) or policy YAML (.yaml) file\n"  # fmt: skip


@pytest.mark.parametrize(
    "changes",
    [{}, {"theta": 0.05}, {"eta": 0.5, "gamma": 0.01, "look_size": 10, "budget": 200}],
    ids=["default", "theta", "small"],
)
def test_the_certify_test_errs_at_most_gamma_at_every_true_eta1(changes):
    """Unforced: P(certified | η1 ≤ η − θ) ≤ γ and P(refuted | η1 ≥ η + θ) ≤ γ, exactly, on a grid of 1001 rates and
    at the edges; undecided is allowed (and happens at η1 = η)."""
    test = CertifySection(policy="policy.pt", **changes).test()
    assert test.looks[-1] == test.looks[0] * len(test.looks) and not test.forced
    rule = decisions(test)
    worst = assert_guarantee(test, rule)
    assert max(worst) >= 0.5 * test.gamma  # the calibration spends γ, not a sliver of it
    if test.theta == 0:
        above, below, _ = forward(rule, np.array([test.threshold]))
        assert above[0] + below[0] <= 2 * test.gamma


@pytest.mark.slow
def test_the_hydra_stage_gives_the_same_gate(tmp_path):
    """`python stages/certify.py certify.policy=…`: the verdict's exit status, the record where the config says."""
    import subprocess
    import sys
    from pathlib import Path

    hard = save_torchscript(Constant(-1.0), tmp_path / "hard_right.pt")
    out = tmp_path / "gate.json"
    script = Path(__file__).resolve().parents[1] / "stages" / "certify.py"
    overrides = [f"certify.policy={hard}", f"certify.out={out}", f"paths.root={tmp_path}", "progress=false"]
    done = subprocess.run([sys.executable, str(script), *overrides], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 1, done.stderr
    assert done.stdout.startswith("REFUTED: eta1 < 0.9: a policy with eta1 >= 0.9 is refuted with probability")
    assert f"For {hard} in roundabout" in done.stdout
    assert json.loads(out.read_text())["verdict"] == "refuted"


@pytest.mark.slow
def test_a_gymnasium_world_is_a_world_to_certify_in(tmp_path, monkeypatch):
    """`--world` naming conf/gym_world/uqdrive_roundabout: uqdrive's roundabout as a Gymnasium env, judged by its
    info's safe set, at its own horizon."""
    write_package(tmp_path / "site", monkeypatch)
    keeper = write_yaml(tmp_path / "keeper.yaml", KEEPER)
    code, record = certify(tmp_path, keeper, "--eta", "0.5", "--world", "uqdrive_roundabout")
    assert code == 0 and (record["world"], record["weather"]) == ("uqdrive_roundabout", "env")
    hard = save_torchscript(Constant(1.0), tmp_path / "hard_left.pt")  # frames: the env renders them
    code, record = certify(tmp_path, hard, "--eta", "0.5", "--world", "uqdrive_roundabout")
    assert code == 1 and record["safe"] == 0
    assert certify(tmp_path, hard, "--world", "nowhere")[0] == 2
    # the same world from a file of the user's own, outside the project: the same rollouts
    own = tmp_path / "myconf/gym_world/mine.yaml"
    own.parent.mkdir(parents=True)
    own.write_text((ROOT / "conf/gym_world/uqdrive_roundabout.yaml").read_text().replace("name: uqdrive_", "name: my_"))
    code, mine = certify(tmp_path, hard, "--eta", "0.5", "--world", str(own))
    assert code == 1 and mine["world"] == "my_roundabout" and mine["outcomes"] == record["outcomes"]
    (tmp_path / "mine.yaml").write_text(own.read_text())
    assert certify(tmp_path, hard, "--world", str(tmp_path / "mine.yaml"))[0] == 2  # not in a gym_world/ folder
