"""DVC deps that cannot go stale: every project file a stage's script imports is covered by the stage's deps."""

import functools
import shlex
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from uqdrive.deps import SRC, files_digest, import_closure, stage_closure

ROOT = Path(__file__).resolve().parents[1]


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_closure_follows_lazy_relative_and_submodule_imports_and_skips_third_party(tmp_path):
    src = tmp_path / "src"
    for name in ("uqdrive/__init__.py", "uqdrive/unused.py", "uqdrive/sub/leaf.py", "uqdrive/sub/sibling.py"):
        write(src / name, "")
    write(src / "uqdrive/sub/__init__.py", "from .leaf import x\n")
    write(src / "uqdrive/sub/mid.py", "import numpy\nfrom . import sibling\n")
    write(src / "uqdrive/top.py", "def later():\n    from uqdrive.sub import mid\n")
    script = write(tmp_path / "stages/run.py", "import os\nimport uqdrive.top\n")
    closure = {p.relative_to(tmp_path).as_posix() for p in import_closure(script, src=src)}
    assert closure == {
        "stages/run.py",
        "src/uqdrive/__init__.py",
        "src/uqdrive/top.py",
        "src/uqdrive/sub/__init__.py",
        "src/uqdrive/sub/leaf.py",
        "src/uqdrive/sub/mid.py",
        "src/uqdrive/sub/sibling.py",
    }


def test_hydra_targets_in_the_configs_are_part_of_every_stage():
    assert SRC / "uqdrive/tracking.py" in stage_closure(ROOT / "stages/report.py", ROOT / "conf")


def test_the_cell_digest_covers_the_rollout_code_the_stage_and_the_posterior_module():
    from uqdrive.safety.runner import code_digest

    closure = import_closure(SRC / "uqdrive/safety/runner.py", ["uqdrive.pipeline.safety_stage", "uqdrive.models.vi"])
    assert {SRC / f"uqdrive/{f}" for f in ("figures.py", "sim/world.py", "models/vi.py", "uq/sequential.py")} <= closure
    assert SRC / "uqdrive/models/hmc.py" not in closure
    assert code_digest(["uqdrive.pipeline.safety_stage", "uqdrive.models.vi"]) == files_digest(closure, SRC)


@dataclass(frozen=True)
class StageCode:
    """A DVC stage's listed deps and the project files its script imports."""

    name: str
    deps: list[Path]
    imports: list[Path]

    def covered(self, f: Path) -> bool:
        return any(f == d or d in f.parents for d in self.deps)


def with_gym_world() -> Path:
    """A copy of the pipeline's definition with the Gymnasium proof turned on (its stages exist only then)."""
    project = Path(tempfile.mkdtemp(prefix="uqdrive-gym-dvc-"))
    (project / ".dvc").mkdir()
    (project / ".dvc/config").write_text("[core]\n    no_scm = True\n")
    shutil.copy(ROOT / "dvc.yaml", project / "dvc.yaml")
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    (project / "params.yaml").write_text(yaml.safe_dump({**params, "gym_worlds": ["highway_roundabout"]}))
    return project


@functools.cache
def stages(gym: bool = False) -> tuple[StageCode, ...]:
    """Every stage of dvc.yaml (``gym``: with the Gymnasium proof's stages), its closure computed once per distinct
    script (the matrix stages share one)."""
    from dvc.repo import Repo

    closures: dict[str, list[Path]] = {}
    out = []
    with Repo(str(with_gym_world() if gym else ROOT)) as repo:
        for stage in repo.index.stages:
            script = next(arg for arg in shlex.split(stage.cmd) if arg.endswith(".py"))
            if script not in closures:
                closures[script] = [p.relative_to(ROOT) for p in stage_closure(ROOT / script, ROOT / "conf")]
            out.append(StageCode(stage.name, [Path(d.def_path) for d in stage.deps], closures[script]))
    return tuple(out)


def missing_deps(gym: bool = False) -> dict[str, list[str]]:
    """Stage → project files its script imports that none of its deps covers (a folder covers what is under it)."""
    missing = {s.name: sorted(f.as_posix() for f in s.imports if not s.covered(f)) for s in stages(gym)}
    return {name: files for name, files in missing.items() if files}


GYM = pytest.mark.parametrize("gym", [False, True], ids=["default", "gym_worlds"])


def test_the_gymnasium_proofs_stages_exist_only_when_params_name_a_world():
    assert not [s for s in stages() if s.name.startswith("gym_")]
    assert {s.name.split("@")[0] for s in stages(gym=True) if s.name.startswith("gym_")} == {
        f"gym_{name}"
        for name in (
            "collect",
            "preprocess",
            "train_mcd",
            "train",
            "safety",
            "avoid",
            "acquire",
            "avoid_acquired",
            "acquire_summary",
            "findings",
        )
    }


@GYM
def test_every_stage_depends_on_every_project_file_it_imports(gym):
    missing = missing_deps(gym)
    assert not missing, "\n".join(f"{stage}: {', '.join(files)}" for stage, files in missing.items())


@GYM
def test_no_stage_depends_on_code_it_does_not_import(gym):
    """A listed source file or folder the stage never imports would rerun it for nothing."""
    for stage in stages(gym):
        code = [d for d in stage.deps if d.parts[0] in ("src", "stages")]
        unused = [d.as_posix() for d in code if not any(f == d or d in f.parents for f in stage.imports)]
        assert not unused, f"{stage.name} depends on code it does not import: {unused}"


@GYM
def test_no_stage_imports_a_file_dvc_ignores(gym):
    """Each stage's code dep is `src/uqdrive`, less the tools .dvcignore hides: DVC would not see a change to one."""
    from dvc.repo import Repo

    with Repo(str(ROOT)) as repo:
        hidden = repo.dvcignore.is_ignored_file
        ignored = {s.name: [f.as_posix() for f in s.imports if hidden(str(ROOT / f))] for s in stages(gym)}
        assert repo.dvcignore.is_ignored_file(str(ROOT / "src/uqdrive/tools/cli.py"))  # the check sees .dvcignore
    assert not {name: files for name, files in ignored.items() if files}


@GYM
def test_every_listed_dep_exists_once(gym):
    for stage in stages(gym):
        paths = [d.as_posix() for d in stage.deps]
        assert len(paths) == len(set(paths)), f"{stage.name} lists a dep twice"
        code = [p for p in paths if p.split("/")[0] in ("src", "stages", "conf")]  # not other stages' outputs
        absent = [p for p in code if not (ROOT / p).exists()]
        assert not absent, f"{stage.name} depends on project files that do not exist: {absent}"
