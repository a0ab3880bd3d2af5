from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

import uqdrive.pipeline  # noqa: F401  (registers the ${params:...} resolver)

CONF = Path(__file__).resolve().parents[1] / "conf"


@pytest.fixture
def stage_config(tmp_path):
    """Compose a stage's config on the tiny profile with every output under tmp_path."""

    def make(stage: str, *overrides: str):
        with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
            return compose(stage, overrides=[f"paths.root={tmp_path}", "profile=tiny", "progress=false", *overrides])

    return make
