"""The README's first look, run as written: its `Try it` block's commands, in a clean shell (no activated venv, a
bare PATH), on a copy of the project with the committed run's files, as a fresh clone after `make install` has them.
What it must show: the stages ran the project's interpreter, the controller drives at the training condition, at
least one failure clip is drawn, the report says in its first line what the profile can show, and the clean-up line
restores the committed files, params.yaml included."""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import project_copy

ROOT = Path(__file__).resolve().parents[1]


def quickstart_commands() -> list[str]:
    """The commands of the README's first code block under `## Try it`, one a line, as written."""
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Try it") :]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    return [line for line in block.splitlines() if line.strip()]


def fresh_clone(folder: Path) -> Path:
    """The project as a fresh clone has it (definition, code, the committed run's metrics, plots and dvc.lock, its
    .dvc folder), in one commit; `.venv` is this interpreter's environment (what `make install` would have made)."""
    project = project_copy(folder)
    tracked = subprocess.run(
        ["git", "ls-files", "metrics", "plots", "dvc.lock", ".dvc"], cwd=ROOT, capture_output=True, text=True
    ).stdout.split()
    for name in tracked:
        (project / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / name, project / name)
    (project / ".venv").symlink_to(Path(sys.executable).parent.parent)
    for args in (["init", "-q"], ["add", "-A"], ["-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "c"]):
        subprocess.run(["git", *args], cwd=project, check=True, capture_output=True, timeout=120)
    return project


def clean_shell(project: Path, command: str, home: Path) -> subprocess.CompletedProcess:
    env = {"HOME": str(home), "PATH": "/usr/local/bin:/usr/bin:/bin", "GIT_AUTHOR_NAME": "t", "GIT_COMMITTER_NAME": "t"}
    env |= {"GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_EMAIL": "t@t", "UQDRIVE_MLFLOW_PREFIX": "quickstart"}
    env |= {k: os.environ[k] for k in ("TMPDIR",) if k in os.environ}
    return subprocess.run(
        ["bash", "-c", command], cwd=project, env=env, capture_output=True, text=True, timeout=3600, check=False
    )


def test_the_quickstart_block_lists_what_a_newcomer_runs():
    commands = quickstart_commands()
    assert commands[0].startswith("make install") and "xdg-open reports/report.html" in commands[2]
    assert commands[1].startswith(".venv/bin/dvc exp run -S profile=demo")  # by its path: no venv activated
    assert commands[-1].startswith("git checkout -- params.yaml metrics plots dvc.lock")


@pytest.mark.slow
def test_the_readme_quickstart_runs_as_written_in_a_clean_shell(tmp_path):
    project = fresh_clone(tmp_path)
    committed_params = (project / "params.yaml").read_text()
    home = tmp_path / "home"
    home.mkdir()
    for command in quickstart_commands():
        if command.startswith("make install"):  # the venv is linked in (fresh_clone): no install in a test
            continue
        if command.startswith("xdg-open"):  # no browser here: the file it opens
            assert (project / "reports/report.html").stat().st_size > 0
            report = (project / "reports/report.md").read_text().splitlines()
            assert report[0] == "# uqdrive report" and report[2].startswith("**Profile demo (the README's first look)")
            summary = json.loads((project / "metrics/summary.json").read_text())
            assert summary["eta1.train.mcd"] > 0  # the controllers drive where they were trained
            assert list((project / "data/safety/clips").glob("*.mp4"))  # at least one failure clip drawn
            continue
        done = clean_shell(project, command, home)
        assert done.returncode == 0, f"{command}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
        if command.startswith(".venv/bin/dvc exp show"):
            assert "eta1.train.mcd" in done.stdout
    assert (project / "params.yaml").read_text() == committed_params  # the clean-up line restored it
    status = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no", "--", "params.yaml", "metrics", "plots", "dvc.lock"],
        cwd=project, capture_output=True, text=True,
    ).stdout  # fmt: skip
    assert status == "", status
