"""The MLflow UI opens each experiment with its key metrics as columns and its chart view leading with them: the
experiment's shared view (`uqdrive.runs_view`) names metrics the stage logs, and the UI, opened at `runs_link` in
headless Chromium against a real `mlflow ui` on 127.0.0.1, shows them."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import mlflow
import pytest
from mlflow.tracking import MlflowClient
from omegaconf import OmegaConf
from rendered_plots import FLAGS, INSTALL_HINT, chromium

from uqdrive.runs_view import VIEW_TAG, runs_link
from uqdrive.tracking import stage_run, store_uris

SAFETY_CONFIG = {
    "safety": {"theta": 0.1},
    "model": {"name": "mcd"},
    "scenario": {"name": "roundabout"},
    "weather": {"name": "rain"},
    "noise": 0.1,
    "seed": 0,
}


def safety_runs(root: Path, count: int = 3) -> str:
    """``count`` safety cells logged as the stage logs them; returns the experiment id."""
    for i in range(count):
        with stage_run(root, "safety", OmegaConf.create(SAFETY_CONFIG), run_name=f"cell{i}") as run:
            mlflow.log_metrics({"eta1": 0.5 + i / 10, "eta1_low": 0.4 + i / 10, "eta1_high": 0.6 + i / 10})
    return run.info.experiment_id


def test_each_experiment_opens_on_its_key_metrics_and_compared_keys_the_least_safe_first(tmp_path):
    experiment_id = safety_runs(tmp_path, count=1)
    client = MlflowClient(store_uris(tmp_path)[0])
    view = json.loads(client.get_experiment(experiment_id).tags[VIEW_TAG])
    run = client.search_runs([experiment_id])[0]
    metrics = [c for c in view["selectedColumns"] if c.startswith("metrics.")]
    assert metrics == ["metrics.`eta1`", "metrics.`eta1_low`", "metrics.`eta1_high`"]
    assert {m.removeprefix("metrics.").strip("`") for m in metrics} <= set(run.data.metrics)
    shown_params = {c.removeprefix("params.").strip("`") for c in view["selectedColumns"] if c.startswith("params.")}
    assert {"method", "weather", "noise", "location", "replicate"} <= shown_params
    assert {"method", "weather", "noise", "location", "replicate"} <= set(run.data.params)
    assert (view["orderByKey"], view["orderByAsc"]) == ("metrics.`eta1`", True)
    assert view["compareRunCharts"][0]["metricKey"] == "eta1"
    assert view["compareRunSections"][0]["uuid"] == view["compareRunCharts"][0]["metricSectionId"]


def test_a_link_opens_the_runs_tab_with_the_share_key_in_the_model_training_view():
    link = runs_link("7", port=5001)
    assert link.startswith("http://127.0.0.1:5001/#/experiments/7/runs?")
    assert "viewStateShareKey=uqdrive" in link and "workflowType=machine_learning" in link


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def wait_until_up(url: str, server: subprocess.Popen, timeout_s: float = 120) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert server.poll() is None, "mlflow ui exited"
        try:
            with urllib.request.urlopen(url, timeout=5):
                return
        except OSError:
            time.sleep(1)
    raise TimeoutError(f"mlflow ui did not answer at {url} within {timeout_s:.0f} s")


def page_text(url: str) -> str:
    """The page's visible text as headless Chromium renders it (the UI is a script-built page)."""
    with tempfile.TemporaryDirectory() as profile:
        dom = subprocess.run(
            [chromium(), *FLAGS, f"--user-data-dir={profile}", "--virtual-time-budget=30000", "--dump-dom", url],
            capture_output=True,
            text=True,
            timeout=180,
            check=True,
        ).stdout
    dom = re.sub(r"<(script|style)[^>]*>.*?</\1>", " ", dom, flags=re.S)
    return " ".join(re.sub(r"<[^>]+>", " ", dom).split())


@pytest.mark.slow
def test_the_ui_shows_eta1_and_its_interval_as_columns_sorted_least_safe_first(tmp_path):
    if chromium() is None:
        if os.environ.get("CI"):
            pytest.fail(INSTALL_HINT)
        pytest.skip(INSTALL_HINT)
    experiment_id = safety_runs(tmp_path)
    port = free_port()
    ui = [sys.executable, "-m", "mlflow", "ui", "--host", "127.0.0.1", "--port", str(port), "--workers", "1"]
    server = subprocess.Popen(
        [*ui, "--backend-store-uri", store_uris(tmp_path)[0]],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        wait_until_up(f"http://127.0.0.1:{port}/health", server)
        text = page_text(runs_link(experiment_id, port))
        plain = page_text(runs_link(experiment_id, port).replace("viewStateShareKey=uqdrive&", ""))
    finally:
        os.killpg(server.pid, 15)
        server.wait(timeout=30)
    assert "Sort: eta1" in text, text[:800]
    header = text[text.index("Run Name") : text.index("cell")]
    for name in ("eta1", "eta1_high", "eta1_low", "method"):  # in a 1280-px window; further columns scroll
        assert re.search(rf"\b{name}\b", header), (name, header)
    assert "eta1" not in plain[plain.index("Run Name") : plain.index("cell")], "the check cannot fail"
