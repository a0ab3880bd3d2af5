"""Slow end to end: collect (pybullet autopilot, tiny profile) → preprocess → train mcd, vi, hmc, per experiment."""

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

import uqdrive.pipeline  # noqa: F401  (registers the ${params:...} resolver)
from uqdrive.pipeline.collect_stage import run_collect
from uqdrive.pipeline.preprocess_stage import run_preprocess
from uqdrive.pipeline.train_stage import run_train

CONF = Path(__file__).resolve().parents[1] / "conf"
SCENARIOS = ("obstacle", "roundabout")


@pytest.mark.slow
def test_each_method_beats_the_majority_class_on_collected_frames(tmp_path):
    def config(stage, *overrides):
        with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
            return compose(stage, overrides=[f"paths.root={tmp_path}", "profile=tiny", "progress=false", *overrides])

    for scenario in SCENARIOS:
        # 6 episodes, not the tiny profile's 2: one scenario's 2 episodes give ~160 roundabout frames, too few to learn
        run_collect(config("collect", f"scenario={scenario}", "collect.workers=1", "collect.episodes=6"))
    for experiment in ("avoid", "offline"):  # each on its own scenario and class set, as dvc repro trains them
        run_preprocess(config("preprocess", f"experiment={experiment}"))
        for method in ("mcd", "vi", "hmc"):
            # 6 MCD epochs, not the tiny profile's 3: at 3 the trunk sits at the edge of the majority class
            m = run_train(config("train", f"experiment={experiment}", f"model={method}", "train.mcd.epochs=6"))
            assert m.val_accuracy > m.majority_baseline_accuracy + 0.05, (experiment, method, m)
