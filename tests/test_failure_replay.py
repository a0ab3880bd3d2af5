"""Failure records and `uqdrive replay`: a cell records its failing rollouts worst margin first; replaying one
re-drives exactly the logged rollout (outcome, termination, path bit for bit) in pybullet and in a Gymnasium world,
and its clip has one decodable picture per step; bad input is refused in one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import ALL_TENTHS, compose_stage
from mlflow.tracking import MlflowClient
from PIL import Image
from rendered_plots import chromium, render
from test_gym_world import COIN_ID

from uqdrive.pipeline.avoid_stage import run_avoid
from uqdrive.pipeline.replay_stage import main
from uqdrive.pipeline.safety_stage import plan_cell, run_safety
from uqdrive.replay.redrive import redrive
from uqdrive.report.document import Report
from uqdrive.report.failure_gallery import failures_section
from uqdrive.safety.rollout_log import RolloutLog
from uqdrive.tracking import store_uris

COIN = ("gym_world=uqdrive_roundabout", f"gym_world.env_id={COIN_ID}", "gym_world.name=coin")
COIN_CELL = (*COIN, "gym_world.horizon_steps=12", "++gym_world.env_kwargs.rate=0.8")


def run_cell(root: Path, model: Path, *overrides: str):
    """A tiny safety cell run as a stage runs it, its overrides kept in its record."""
    given = [f"paths.root={root}", "profile=tiny", "progress=false", f"safety.model_path={model}", *ALL_TENTHS]
    given += overrides
    cfg = compose_stage(root, "safety", *given[3:])
    return cfg, run_safety(cfg, overrides=given).cell


@pytest.fixture(scope="module")
def pybullet_cell(tmp_path_factory, random_models):
    root = tmp_path_factory.mktemp("replay-pybullet")
    cfg, cell = run_cell(root, random_models["mcd"], "model=mcd", "weather=rain", "safety.clips=1")
    return root, cfg, cell


def clip_frames(path: Path) -> int:
    capture, frames = cv2.VideoCapture(str(path)), 0
    while capture.read()[0]:
        frames += 1
    return frames


def test_a_cell_records_each_failing_rollout_worst_margin_first(pybullet_cell):
    _, _, cell = pybullet_cell
    failing = [i for i, outcome in enumerate(cell.outcomes) if outcome == "0"]
    assert failing and sorted(f.index for f in cell.failures) == failing
    margins = [f.margin for f in cell.failures]
    assert margins == sorted(margins) and margins == sorted(cell.margins[i] for i in failing)
    for f in cell.failures:
        assert f.seed == cell.base_seed + f.index and f.condition == "roundabout-rain-noise0.0"
        assert 0 <= f.step <= f.steps and f.segment in ("approach", "ring", "exit arm") and f.margin < 0
        assert f.cause in ("collision", "off road", "left lane", "short of the goal", "handed over")


def test_the_cell_logs_its_worst_failures_clip_to_its_mlflow_run(pybullet_cell):
    root, _, cell = pybullet_cell
    clip = root / "data/safety/clips" / f"{cell.name}-seed{cell.failures[0].seed}.mp4"
    assert clip_frames(clip) == cell.failures[0].steps and not clip.with_suffix(".gif").exists()  # the report's
    assert len(list((root / "data/safety/clips").glob("*.mp4"))) == 1  # safety.clips=1: the worst only
    client = MlflowClient(store_uris(root)[0])
    (run,) = client.search_runs([client.get_experiment_by_name("uqdrive/safety").experiment_id])
    assert [a.path for a in client.list_artifacts(run.info.run_id, "failures")] == [f"failures/{clip.name}"]


def test_a_reused_cell_draws_the_clips_a_larger_count_asks_for_and_logs_their_seconds(
    pybullet_cell, random_models, tmp_path
):
    source, _, cell = pybullet_cell
    assert len(cell.failures) >= 2
    root = tmp_path / "project"
    shutil.copytree(source, root)
    _, again = run_cell(root, random_models["mcd"], "model=mcd", "weather=rain", "safety.clips=2")
    assert again == cell  # reused: nothing simulated again
    drawn = sorted(p.name for p in (root / "data/safety/clips").glob("*.mp4"))
    assert drawn == sorted(f"{cell.name}-seed{f.seed}.mp4" for f in cell.failures[:2])
    client = MlflowClient(store_uris(root)[0])
    runs = client.search_runs([client.get_experiment_by_name("uqdrive/safety").experiment_id])
    reused = [r for r in runs if r.data.tags["reused"] == "true"]
    assert len(reused) == 1 and reused[0].data.metrics["clip_seconds"] > 0


def test_replay_re_drives_the_logged_rollout_exactly_and_writes_one_picture_per_step(
    pybullet_cell, tmp_path, capsys, monkeypatch
):
    root, cfg, cell = pybullet_cell
    worst = cell.failures[0]
    plan = plan_cell(cfg)
    logged = RolloutLog(cfg.safety.rollout_log, plan.key, cell.base_seed).load()[worst.index]
    again = redrive(plan.job, worst.index).result
    assert (again.termination, again.steps, again.verdict.safe, again.verdict.margin) == (
        logged.termination,
        logged.steps,
        logged.verdict.safe,
        logged.verdict.margin,
    )
    assert np.array_equal(again.x, logged.x) and np.array_equal(again.y, logged.y)

    monkeypatch.chdir(tmp_path)
    record = root / "metrics/safety" / f"{cell.name}.json"
    assert main([str(record), "--first-failure", "--out", "clips"]) == 0
    printed = capsys.readouterr().out
    assert "matches the record" in printed and f"seed {worst.seed}" in printed
    mp4 = tmp_path / "clips" / f"{cell.name}-seed{worst.seed}.mp4"
    assert clip_frames(mp4) == worst.steps == logged.steps
    with Image.open(mp4.with_suffix(".gif")) as gif:
        assert gif.n_frames == worst.steps and gif.size[0] >= 640  # labels at least 10 px high: full size
        assert [_failure_marked(gif, k) for k in (worst.step - 1, worst.step)] == [False, True]
    assert main([str(record), "--seed", str(cell.failures[-1].seed), "--out", "clips"]) == 0


def _failure_marked(gif: Image.Image, step: int) -> bool:
    """Whether picture ``step`` (counted from 0, as the record counts steps) shows the failure's banner: the
    banner's pale red fill above the top-down view."""
    from uqdrive.replay.video import BANNER, TOP_DOWN

    gif.seek(step)
    picture = np.asarray(gif.convert("RGB"))
    x, y, w, _ = TOP_DOWN
    banner = picture[y + 24 : y + 42, x + 4 : x + w - 4].reshape(-1, 3).astype(int)
    pale_red = (np.abs(banner - BANNER[::-1]) <= 8).all(axis=1)  # BGR → RGB
    return bool(pale_red.mean() > 0.3)


def test_a_replay_that_differs_from_its_record_says_so_and_fails(pybullet_cell, tmp_path, capsys):
    root, _, cell = pybullet_cell
    data = json.loads((root / "metrics/safety" / f"{cell.name}.json").read_text())
    data["failures"][0]["path_sha256"] = "0" * 64  # a record of another path than the seed drives
    record = tmp_path / "cell.json"
    record.write_text(json.dumps(data))
    assert main([str(record), "--first-failure", "--out", str(tmp_path)]) == 1
    assert "DIFFERS from the record: path sha256" in capsys.readouterr().out
    assert not list(tmp_path.glob("*.mp4"))


@pytest.mark.parametrize(
    "change, argv, message",
    [
        (None, ["--seed", "5"], "--seed 5: cell mcd-seed0-roundabout-rain-noise0.0 never ran it (it ran seeds 100000"),
        ({"config_hash": "0123456789abcdef"}, ["--first-failure"], "identity changed since it ran (0123456789abcdef"),
        (
            {"location": "obstacle_road"},
            ["--first-failure"],
            "is from world 'obstacle_road'; its overrides now compose",
        ),
        ({"overrides": []}, ["--first-failure"], "names no overrides to compose its cell from"),
        ({"failures": []}, ["--first-failure"], "has no failing rollout; choose one with --seed"),
        ({"eta1": "high"}, ["--first-failure"], "is not a safety cell's record"),
    ],
)
def test_bad_input_is_refused_in_one_line(pybullet_cell, tmp_path, capsys, change, argv, message):
    root, _, cell = pybullet_cell
    data = json.loads((root / "metrics/safety" / f"{cell.name}.json").read_text())
    record = tmp_path / "cell.json"
    record.write_text(json.dumps({**data, **(change or {})}))
    assert main([str(record), *argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not list(tmp_path.glob("*.mp4"))


def test_a_missing_record_is_refused_in_one_line(tmp_path, capsys):
    assert main([str(tmp_path / "none.json"), "--first-failure"]) == 2
    assert "does not exist; pass a safety cell's record" in capsys.readouterr().err


def test_replay_in_a_gymnasium_world_re_drives_the_failure_exactly(tmp_path, random_models, capsys, monkeypatch):
    cfg, cell = run_cell(tmp_path, random_models["mcd"], "model=mcd", *COIN_CELL)
    assert cell.failures and all(f.cause == "collision" and f.margin is None for f in cell.failures)
    assert [f.index for f in cell.failures] == sorted(f.index for f in cell.failures)  # no margin: by index
    plan = plan_cell(cfg)
    logged = RolloutLog(cfg.safety.rollout_log, plan.key, cell.base_seed).load()
    for f in cell.failures:
        again = redrive(plan.job, f.index).result
        assert (
            (again.termination, again.steps)
            == (logged[f.index].termination, logged[f.index].steps)
            == (
                f.termination,
                f.steps,
            )
        )
        assert np.array_equal(again.x, logged[f.index].x) and f.segment.endswith("in the episode")
    monkeypatch.chdir(tmp_path)
    record = tmp_path / "metrics/safety" / f"{cell.name}.json"
    assert main([str(record), "--first-failure", "--out", "clips"]) == 0
    assert clip_frames(tmp_path / "clips" / f"{cell.name}-seed{cell.failures[0].seed}.mp4") == cell.failures[0].steps


def gallery(root: Path, cell) -> tuple[Report, int]:
    report = Report(root, root / "reports")
    shown = failures_section(report, [cell], root / "data/safety/clips", root / "metrics/safety", [cell.condition])
    return report, shown


def test_the_report_gallery_shows_the_worst_clip_with_a_replay_command_that_works(pybullet_cell, capsys, monkeypatch):
    root, _, cell = pybullet_cell
    report, shown = gallery(root, cell)
    worst = cell.failures[0]
    command = f"uqdrive replay metrics/safety/{cell.name}.json --seed {worst.seed}"
    assert shown == 1 and f"`{command}`" in report.markdown  # safety.clips=1: one clip drawn
    assert (root / "reports/failures/replays.txt").read_text() == command + "\n"
    assert f'src="failures/{cell.name}-seed{worst.seed}.gif"' in report.html()
    with Image.open(root / "reports/failures" / f"{cell.name}-seed{worst.seed}.gif") as gif:  # made from the MP4
        assert gif.n_frames == worst.steps
    assert "mcd's rain failures (4 of 4 rollouts) are 100 % off road on the approach" in report.markdown
    monkeypatch.chdir(root)
    assert main([*command.split()[2:], "--out", str(root / "replayed")]) == 0
    assert "matches the record" in capsys.readouterr().out


def test_every_gallery_image_loads_in_a_browser(pybullet_cell):
    if chromium() is None:
        pytest.skip("no Chromium: `make chromium` installs it")
    root, _, cell = pybullet_cell
    report, _ = gallery(root, cell)
    page = root / "reports" / "gallery.html"
    page.write_text(report.html())
    images = [d for d in render(page, timeout_s=120) if d.kind == "image"]
    assert [d.plot for d in images] == [f"failures/{cell.name}-seed{cell.failures[0].seed}.gif"]
    assert all(d.marks == 1 and d.width > 0 for d in images)


def test_in_a_gymnasium_world_that_draws_itself_the_clip_shows_its_render_and_the_path_is_unchanged(
    tmp_path, random_models
):
    cfg, cell = run_cell(tmp_path, random_models["mcd"], "model=mcd", "gym_world=uqdrive_roundabout")
    plan = plan_cell(cfg)
    logged = RolloutLog(cfg.safety.rollout_log, plan.key, cell.base_seed).load()
    worst = cell.failures[0]
    watched = redrive(plan.job, worst.index)
    assert all(view is not None and view.ndim == 3 for view in watched.views)  # the env's own render, every step
    assert np.array_equal(watched.result.x, logged[worst.index].x) and watched.result.steps == worst.steps


@pytest.mark.slow
def test_each_avoid_cell_draws_its_worst_failure_and_logs_it_to_its_run(avoid_config, tmp_path):
    result = run_avoid(avoid_config("model=mcd", "avoid.clips=1"))
    client = MlflowClient(store_uris(tmp_path)[0])
    runs = client.search_runs([client.get_experiment_by_name("uqdrive/avoid").experiment_id])
    by_cell = {r.data.tags["cell"]: r for r in runs if "cell" in r.data.tags}
    drawn = 0
    for condition, cells in result.cells.items():
        for mode, cell in cells.items():
            name = f"mcd-seed0-{condition}-{mode}"
            logged = [a.path for a in client.list_artifacts(by_cell[name].info.run_id, "failures")]
            if not cell.failures:
                assert logged == []
                continue
            worst = cell.failures[0]
            clip = tmp_path / "data/avoid/mcd-seed0/clips" / f"{name}-seed{worst.seed}.mp4"
            assert logged == [f"failures/{clip.name}"] and clip_frames(clip) == worst.steps
            drawn += 1
    assert drawn  # the random-weight controller fails somewhere
