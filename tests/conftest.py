import functools
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml
from hydra import compose, initialize_config_dir

import uqdrive.pipeline  # noqa: F401  (registers the ${params:...} resolver)
from uqdrive.models.schemas import register_schemas as register_models
from uqdrive.policy.warnings import register_schema as register_warning
from uqdrive.sim.config import register_schemas as register_world

for register in (register_world, register_warning, register_models):  # the config groups' defaults, as the stages do
    register()

CONF = Path(__file__).resolve().parents[1] / "conf"


def compose_stage(root: Path, stage: str, *overrides: str):
    """A stage's config on the tiny profile with every output under ``root``."""
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(stage, overrides=[f"paths.root={root}", "profile=tiny", "progress=false", *overrides])


@pytest.fixture
def stage_config(tmp_path):
    """Compose a stage's config on the tiny profile with every output under tmp_path."""
    return functools.partial(compose_stage, tmp_path)


@pytest.fixture(autouse=True)
def one_thread():
    """Test tensors are tiny: a second intra-op thread only adds synchronisation (up to 40x slower
    when the other core is busy, as it is in CI)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def cell_result(record: dict) -> dict:
    """A safety cell's record without its provenance (how long it took, the overrides that composed it): what two
    runs of one cell must agree on."""
    return {k: v for k, v in record.items() if k not in ("seconds", "overrides")}


# The random-weight models predict all 21 tenths: stages using them widen the experiment's class set to match.
ALL_TENTHS = ("experiment.bins.low=-1.0", "experiment.bins.high=1.0")


@pytest.fixture(scope="session")
def random_models(tmp_path_factory):
    """models/{mcd,vi,hmc}.pt with seeded random weights: closed-loop plumbing needs a posterior, not a good one."""
    from uqdrive.bench.posterior_bench import random_posteriors
    from uqdrive.models import save_posterior

    folder = tmp_path_factory.mktemp("random-models")
    posteriors = random_posteriors(torch.Generator().manual_seed(0))
    return {method: save_posterior(post, folder / f"{method}.pt") for method, post in posteriors.items()}


@pytest.fixture
def avoid_config(stage_config, random_models):
    """An avoid stage config driving the random-weight models (overrides appended)."""

    def make(*overrides: str):
        folder = random_models["mcd"].parent
        return stage_config("avoid", *ALL_TENTHS, f"avoid.model_path={folder}/${{model.name}}.pt", *overrides)

    return make


def pytest_collection_modifyitems(items):
    """The longest test first, the `dvc repro` one, then the other end-to-end tests (stable otherwise): each
    pytest-xdist worker takes the next test file in this order, so the longest runs beside the rest of the suite
    instead of after most of it."""
    items.sort(key=lambda item: (item.path.name != "test_dvc_pipeline.py", item.get_closest_marker("slow") is None))


def dvc(project: Path, *args: str, timeout: float = 300) -> str:
    """``dvc <args>`` in ``project`` with this interpreter's DVC; fails the test with DVC's own output."""
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    result = subprocess.run(
        [sys.executable, "-m", "dvc", *args], cwd=project, env=env, capture_output=True, text=True, timeout=timeout
    )
    assert result.returncode == 0, result.stdout + result.stderr
    return result.stdout


def project_copy(folder: Path, **params) -> Path:
    """The pipeline's definition, configs, stages and package copied into ``folder``/project, with ``params``
    updated in its params.yaml (its key order kept: `dvc exp show`'s); returns the project folder."""
    root, project = CONF.parent, folder / "project"
    project.mkdir()
    for name in ("dvc.yaml", "params.yaml", ".gitignore", ".dvcignore"):
        shutil.copy(root / name, project / name)
    for name in ("conf", "stages", "src"):
        shutil.copytree(root / name, project / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    values = yaml.safe_load((project / "params.yaml").read_text())
    (project / "params.yaml").write_text(yaml.safe_dump({**values, **params}, sort_keys=False))
    return project
