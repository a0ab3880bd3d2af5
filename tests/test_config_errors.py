"""A bad config value ends a stage with one line (key, value, what is allowed), exit code 2, and no output."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import uqdrive
from uqdrive.schema import ConfigError
from uqdrive.stage import stage_main

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("stage", "overrides", "message"),
    [
        ("safety", ["safety.theta=2"], "error: safety.theta=2: input should be less than 1"),
        (
            "collect",
            ["scenario=straight", "noise=-0.1"],
            "error: noise=-0.1: input should be greater than or equal to 0",
        ),
        (
            "collect",
            ["scenario=straight", "outputs=x"],
            "error: outputs='x' is not known; choose one of ['auto', 'pipeline']",
        ),
        *(  # a key no config has (a typo): Hydra refuses the plain form while composing, the schema the `+` form;
            # either way one line with the key it resembles
            (
                "collect",
                [override],
                "error: collect.episodez: unknown key; did you mean 'episodes'? known keys: out, name, metrics, "
                "mosaic, episodes, base_seed, workers, mosaic_rows, mosaic_columns",
            )
            for override in ("collect.episodez=3", "+collect.episodez=3")
        ),
        (
            "collect",
            ["weather=snow"],
            "error: In 'collect': Could not find 'weather/snow'; Available options in "
            "'weather':; afternoon; clear_noon; fog; rain",
        ),
        (  # a structured key: the error shows what one looks like
            "envelope",
            ["envelope.axes=bogus"],
            "error: envelope.axes='bogus': input should be a valid tuple; expected [{key: …, range: […, …]}, …]",
        ),
        (  # a group's schema (its defaults) is no option of the group
            "safety",
            ["weather=weather_schema"],
            "error: In 'safety': Could not find 'weather/weather_schema'; Available options in "
            "'weather':; afternoon; clear_noon; fog; rain",
        ),
    ],
)
def test_a_bad_value_prints_one_line_and_writes_nothing(tmp_path, stage, overrides, message):
    result = subprocess.run(
        [sys.executable, str(ROOT / "stages" / f"{stage}.py"), "profile=tiny", *overrides],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT / "src")},
    )
    assert result.returncode == 2
    assert result.stderr.splitlines() == [message]
    assert result.stdout == ""
    assert not list(tmp_path.iterdir())  # no output, no store, not even the run folder Hydra made for it


def test_only_config_errors_become_one_line():
    @stage_main
    def bad_value(_cfg: object) -> None:
        raise ConfigError("x=1 must be 2")

    @stage_main
    def bug(_cfg: object) -> None:
        raise KeyError("a bug keeps its traceback")

    with pytest.raises(SystemExit) as stopped:
        bad_value(None)
    assert stopped.value.code == 2
    with pytest.raises(KeyError):
        bug(None)


def run_script(stage: str, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(ROOT / "stages" / f"{stage}.py"), *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT / "src")},
    )


@pytest.mark.slow
def test_the_resolved_job_config_and_the_help_print_without_running(tmp_path):
    shown = run_script("safety", "model=vi", "--cfg", "job", "--resolve", cwd=tmp_path)
    assert shown.returncode == 0, shown.stderr
    assert "cell: vi-seed0-roundabout-clear_noon-noise0.0" in shown.stdout
    assert f"out: {tmp_path}/outputs/" in shown.stdout  # an ad-hoc run writes under its own folder
    helped = run_script("safety", "--help", cwd=tmp_path)
    assert helped.returncode == 0 and "weather: afternoon, clear_noon, fog, rain" in helped.stdout
    assert "schema" not in helped.stdout.split("== Config ==")[0]


@pytest.mark.slow
def test_a_model_file_of_random_bytes_is_one_line_naming_it_without_torchs_advice(tmp_path):
    (tmp_path / "vi.pt").write_bytes(np.random.default_rng(0).bytes(4096))
    result = run_script("safety", "profile=tiny", "model=vi", f"safety.model_path={tmp_path}/vi.pt", cwd=tmp_path)
    assert result.returncode == 2 and result.stdout == ""
    (line,) = result.stderr.splitlines()
    assert line.startswith(f"error: safety.model_path={tmp_path}/vi.pt: is not a uqdrive model file (torch cannot ")
    assert line.endswith("; dvc repro train@offline-vi") and "weights_only" not in line and "issue" not in line


def test_the_version_is_one_line(capsys):
    from uqdrive.tools.cli import main

    assert main(["--version"]) == 0 and capsys.readouterr().out == f"uqdrive {uqdrive.__version__}\n"


@pytest.mark.slow
def test_an_empty_model_file_is_one_line_naming_the_key_and_the_stage_that_trains_it(tmp_path):
    (tmp_path / "vi.pt").write_bytes(b"")
    result = run_script("safety", "profile=tiny", "model=vi", f"safety.model_path={tmp_path}/vi.pt", cwd=tmp_path)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.splitlines() == [
        f"error: safety.model_path={tmp_path}/vi.pt: is empty (0 bytes): not a uqdrive model file; "
        "dvc repro train@offline-vi"
    ]
