"""`dvc repro` of the Gymnasium proof's acquisition on the tiny profile, in a copy of the project: HighwayEnv's
expert data, an MCD controller, its sweep, one round of data acquisition where the sweep flagged it, and the warning
system driven again by the controller the round ended with (gym_avoid_acquired)."""

import subprocess

import pytest
from conftest import dvc, project_copy

from uqdrive.analysis.acquisition_summary import AcquisitionSummary
from uqdrive.avoid.results import read_avoid_results
from uqdrive.records import read_record

WORLD = "highway_roundabout"


@pytest.mark.slow
def test_dvc_repro_acquires_in_a_gym_world_and_reruns_the_warnings_with_the_acquired_controller(tmp_path):
    project = project_copy(
        tmp_path, profile="tiny", methods=["mcd"], heads=[], replicates=[0], gym_worlds=[WORLD], acquire_rounds=1
    )
    acquire_conf = project / "conf/gym_acquire.yaml"  # the tiny profile's θ for the checks too: 4 runs, not 49
    acquire_conf.write_text(acquire_conf.read_text().replace("check_theta: 0.15", "check_theta: null"))
    subprocess.run(["git", "init", "-q"], cwd=project, check=True, timeout=60)
    dvc(project, "init", "-q")

    targets = (f"gym_acquire_summary@{WORLD}", "gym_avoid_acquired")
    dvc(project, "repro", *targets, timeout=1500)
    summary = read_record(AcquisitionSummary, project / f"metrics/{WORLD}/acquisition.json", "acquire_summary")
    assert [(a.method, a.replicate) for a in summary.controllers] == [("mcd", 0)]
    assert {c.round for c in summary.checks} == {0, 1}  # the behaviour-cloned controller and one round, checked
    folder = project / f"data/acquire/{WORLD}/mcd-seed0"
    assert (folder / "controller.pt").read_bytes() == (folder / "round1/models/mcd/seed0.pt").read_bytes()
    (acquired,) = read_avoid_results(project / f"metrics/{WORLD}/avoid_acquired", ["mcd"], [0])
    assert set(acquired.cells) == {"known", "aggressive"}
    assert all(cell.estimate.n > 0 for modes in acquired.cells.values() for cell in modes.values())
    driven = (project / f"cache/rollouts/{WORLD}/avoid_acquired/mcd-seed0").rglob("*.jsonl")
    assert next(driven, None) is not None  # its own rollouts, not the behaviour-cloned controller's read back
    assert "Data and pipelines are up to date" in dvc(project, "status", *targets)
