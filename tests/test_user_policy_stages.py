"""A user's policy in the stages that drive (README "Your own controller"): `safety.policy` drives a safety cell in
place of a trained model, rollout for rollout as the policy drives on its own, with η2 and mutual information from
its draws, named by its file; `envelope.policy` (and so the rare-event stage) drives the map; a policy answering
wrongly fails in one line before any rollout."""

from __future__ import annotations

import pytest
from user_policy_kit import write_package, write_yaml

from uqdrive.envelope.plan import build_envelope
from uqdrive.pipeline.safety_stage import plan_cell, run_safety
from uqdrive.policy.policy_files import UserPolicySpec, load_policy
from uqdrive.safety.rollout import run_rollouts
from uqdrive.schema import ConfigError
from uqdrive.sim import DrivingEnv

BAYES = "policy:\n  _target_: h50_user_policies.policies.BayesianKeeper\n"


@pytest.fixture
def bayes(tmp_path, monkeypatch):
    write_package(tmp_path / "site", monkeypatch)
    return write_yaml(tmp_path / "bayes.yaml", BAYES)


def test_a_safety_cell_drives_a_users_policy_as_it_drives_on_its_own(stage_config, bayes, tmp_path):
    cfg = stage_config("safety", f"safety.policy={bayes}", "safety.horizon_s=3", "executor.workers=1")
    cell = run_safety(cfg).cell
    assert cell.method == "bayes" and cell.estimate.value == cell.outcomes.count("1") / cell.estimate.n
    assert cell.mean_eta2 is not None and cell.mean_mutual_information > 0  # the policy's own draws
    assert (tmp_path / f"metrics/safety/bayes-seed0-roundabout-clear_noon-noise{0.0!r}.json").exists()

    job = plan_cell(cfg).job
    spec = load_policy(bayes, speed=cfg.safety.speed, eps=cfg.safety.eps)
    seeds = [job.base_seed + i for i in range(cell.estimate.n)]
    with DrivingEnv(job.camera, job.vehicle, job.control_hz, job.horizon_s) as env:
        alone = run_rollouts([env], spec.build(job.control_hz), seeds, [job.where] * len(seeds))
    assert "".join("1" if r.verdict.safe else "0" for r in alone) == cell.outcomes
    assert [r.steps for r in alone] == [int(s) for s in _steps(tmp_path, cfg)]


def _steps(tmp_path, cfg) -> list[int]:
    import csv

    with (tmp_path / "plots/safety/cells" / f"{cfg.safety.cell}.csv").open() as f:
        return [int(row["steps"]) for row in csv.DictReader(f)]


def test_the_envelope_and_so_the_rare_stage_drive_a_users_policy_without_a_trained_model(stage_config, bayes):
    envelope = build_envelope(stage_config("envelope", f"envelope.policy={bayes}", "envelope.model_path=/nowhere.pt"))
    assert envelope.method == "bayes" and isinstance(envelope.policy, UserPolicySpec)
    assert envelope.stage.envelope.out.endswith("metrics/envelope/bayes-seed0.json")


def test_a_policy_answering_out_of_range_fails_in_one_line_before_any_rollout(stage_config, tmp_path, monkeypatch):
    write_package(tmp_path / "site", monkeypatch)
    target = "h50_user_policies.policies.BadAction"
    bad = write_yaml(tmp_path / "bad.yaml", f"policy:\n  _target_: {target}\n  what: steer\n")
    with pytest.raises(ConfigError) as err:
        run_safety(stage_config("safety", f"safety.policy={bad}", "executor.workers=1"))
    assert "\n" not in str(err.value) and "h50_user_policies.policies.BadAction" in str(err.value)
    assert not (tmp_path / "metrics").exists()
