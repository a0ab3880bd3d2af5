"""The committed run is read by the code it ships with: a schema change that orphans the committed records fails
here, not in a newcomer's first command. The report renders from the committed metrics and plots, `uqdrive findings`
and `uqdrive redecide` run on them, every committed safety record has its `failures`, the README's replay example
names a committed cell that has one, and every output dvc.yaml declares has an entry in the committed dvc.lock (else
`dvc exp run` opens with "No file hash info found" warnings)."""

import json
import os
import re
import shutil
from pathlib import Path

import pytest
import yaml
from conftest import compose_stage

from uqdrive.pipeline.report_stage import run_report
from uqdrive.tools.cli import main

# the checkout's committed run; UQDRIVE_RUN_ROOT: another project folder's run (a fresh `make repro`, before committing)
ROOT = Path(os.environ.get("UQDRIVE_RUN_ROOT") or Path(__file__).resolve().parents[1])


def committed_safety_records() -> list[Path]:
    return sorted((ROOT / "metrics/safety").glob("*.json"))


def test_every_committed_safety_record_has_its_failures_and_the_readme_replays_one_that_failed():
    records = {p.name: json.loads(p.read_text()) for p in committed_safety_records()}
    assert records and all("failures" in r for r in records.values()), [
        n for n, r in records.items() if "failures" not in r
    ]
    example = re.search(r"uqdrive replay (metrics/safety/\S+\.json) --first-failure", (ROOT / "README.md").read_text())
    assert example and records[Path(example.group(1)).name]["failures"], "README's replay example has no failure"


@pytest.mark.slow
def test_the_report_renders_from_the_committed_records(tmp_path):
    for name in ("params.yaml", "metrics", "plots"):
        copy = shutil.copytree if (ROOT / name).is_dir() else shutil.copy
        copy(ROOT / name, tmp_path / name)
    files = run_report(compose_stage(tmp_path, "report", "outputs=pipeline"))
    assert files.html.stat().st_size > 0 and files.markdown.read_text().startswith("# uqdrive report")


def test_findings_and_redecide_run_on_the_committed_findings(tmp_path, capsys):
    assert main(["findings", str(ROOT / "metrics/findings.json")]) == 0
    assert capsys.readouterr().out.strip()
    assert main(["redecide", str(ROOT / "metrics/findings.json"), "--out", str(tmp_path / "findings.json")]) == 0
    assert (tmp_path / "findings.json").exists()


def test_every_declared_output_has_its_entry_in_the_committed_lock():
    from dvc.repo import Repo

    locked = {o["path"] for s in yaml.safe_load((ROOT / "dvc.lock").read_text())["stages"].values() for o in s["outs"]}
    with Repo(str(ROOT)) as repo:
        declared = {str(out.def_path) for stage in repo.index.stages for out in stage.outs}
    assert declared <= locked, sorted(declared - locked)
