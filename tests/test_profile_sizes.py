"""Each built-in posterior's training sizes are written once: the paper's in conf/train_sizes/paper.yaml, each
profile writing only what it changes (no value equal to the one it inherits), and every profile's composed sizes
are those the profiles spelled out whole before (the literals below), in the train stage and in every other stage
that composes a profile."""

from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

CONF = Path(__file__).resolve().parents[1] / "conf"
METHODS = ("mcd", "vi", "hmc", "ensemble", "laplace")


def sizes(mcd, vi, hmc, ensemble, laplace) -> dict:
    """(epochs, batch_size, lr) for the three fitted heads and the trunk, hmc's and ensemble's own fields."""
    fitted = ("epochs", "batch_size", "lr")
    return {
        "mcd": dict(zip(fitted, mcd)),
        "vi": dict(zip(fitted, vi)),
        "hmc": dict(
            zip(("chains", "samples", "warmup", "thin", "bayesian_layers", "metric", "rhat_target_share"), hmc)
        ),
        "ensemble": dict(zip(("members", *fitted), ensemble)),
        "laplace": dict(zip(fitted, laplace)),
    }


PAPER = sizes((25, 16, 1e-4), (25, 16, 1e-3), (4, 150, 300, 4, 1, "laplace", 0.95), (10, 25, 64, 1e-3), (10, 64, 1e-3))
QUICK = sizes((8, 16, 3e-4), (30, 64, 1e-3), (4, 200, 100, 1, 1, "laplace", 0.9), (5, 15, 64, 1e-3), (5, 64, 1e-3))
TINY = sizes((3, 16, 1e-3), (3, 64, 1e-3), (4, 10, 20, 1, 1, "laplace", 0.9), (3, 3, 64, 3e-3), (2, 64, 1e-3))
EXPECTED = {
    "paper": PAPER,
    "quick": QUICK,
    "study": QUICK,
    "tiny": TINY,
    "demo": {**TINY, "mcd": dict(epochs=6, batch_size=32, lr=1e-3)},
}


def composed_sizes(stage: str, profile: str) -> dict:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(stage, overrides=[f"profile={profile}"])
    return {m: OmegaConf.to_container(cfg.train[m]) for m in METHODS}


@pytest.mark.parametrize("profile", sorted(EXPECTED))
def test_each_profile_composes_the_sizes_it_always_had(profile):
    assert composed_sizes("train", profile) == EXPECTED[profile]
    assert composed_sizes("safety", profile) == EXPECTED[profile]  # a stage that trains nothing sees the same


def test_train_reads_a_methods_sizes_through_its_model_config():
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose("train", overrides=["profile=quick", "model=hmc", "train.hmc.samples=7"])
    assert cfg.model.samples == 7 and cfg.model.warmup == QUICK["hmc"]["warmup"]


def inherited(profile: str) -> dict:
    """The sizes a profile starts from: the paper's file or the profile it builds on, through its defaults list."""
    base: dict = {m: {} for m in METHODS}
    for entry in yaml.safe_load((CONF / "profile" / f"{profile}.yaml").read_text()).get("defaults", []):
        if entry == "/train_sizes/paper":
            base = yaml.safe_load((CONF / "train_sizes" / "paper.yaml").read_text())
        elif entry != "_self_":
            base = effective(entry)
    return base


def effective(profile: str) -> dict:
    own = yaml.safe_load((CONF / "profile" / f"{profile}.yaml").read_text()).get("train") or {}
    return {m: {**inherited(profile)[m], **own.get(m, {})} for m in METHODS}


def test_each_size_is_written_once():
    train = yaml.safe_load((CONF / "train.yaml").read_text())["train"]
    assert not set(train) & set(METHODS), "conf/train.yaml repeats a method's sizes"
    for path in sorted((CONF / "profile").glob("*.yaml")):
        own = yaml.safe_load(path.read_text()).get("train") or {}
        base = inherited(path.stem)
        repeated = [f"{m}.{k}" for m in set(own) & set(METHODS) for k, v in own[m].items() if base[m].get(k) == v]
        assert not repeated, f"{path.name} repeats what it inherits: {repeated}"
        assert effective(path.stem) == EXPECTED[path.stem]
