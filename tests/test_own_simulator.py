"""A simulator of the user's own, as the README's "Your own simulator" wires it: a Gymnasium env of a new family
and its hooks class (the README's example, verbatim) named ``module:Class``, in a package written into the test's
temporary folder (never installed), collected with its expert, trained on and certified by config alone; an edit of
its safe-set rule (or of the env, or of a policy's class) is a new cell, never a replay; a bug in its code is one
line with the seed and step."""

from __future__ import annotations

import json
import sys
import textwrap
from pathlib import Path

import pytest

from uqdrive.pipeline.certify_stage import run_certify
from uqdrive.pipeline.collect_stage import run_collect
from uqdrive.pipeline.preprocess_stage import run_preprocess
from uqdrive.pipeline.safety_stage import run_safety
from uqdrive.pipeline.train_stage import run_train
from uqdrive.schema import ConfigError
from uqdrive.sim.gym_hooks import WorldFailure

pytestmark = pytest.mark.filterwarnings("ignore:.*Overriding environment h50_drift")  # re-imported after an edit
PACKAGE = "h50_drift"
ENVS = '''
"""A car on a straight lane pushed left by a steady wind; its steering pushes it back."""

import gymnasium
import numpy as np
from gymnasium import spaces


class Drift(gymnasium.Env):
    observation_space = spaces.Box(0, 255, (48, 64, 3), np.uint8)  # a bright column where the car is
    action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.y, self.v = 0.0, float(self.np_random.uniform(-0.3, 0.3)), 6.0
        return self._obs(), {}

    def step(self, action):
        self.x += 0.4
        self.y += 0.3 * float(action[0]) + 0.1 + float(self.np_random.normal(0.0, 0.02))
        return self._obs(), 0.0, False, False, {}

    def _obs(self):
        image = np.full((48, 64, 3), 40, np.uint8)
        column = int(np.clip(32 - 10 * self.y, 0, 63))  # y is to the left: left of the picture's centre
        image[:, max(column - 2, 0) : column + 3] = 220
        return image


gymnasium.register("h50_drift/Drift-v0", entry_point="h50_drift.envs:Drift")
'''
README = Path(__file__).resolve().parents[1] / "README.md"


def readme_hooks() -> str:
    """The hooks class of the README's "Your own simulator", verbatim: the example is the tested code."""
    section = README.read_text().split("## Your own simulator", 1)[1]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


POLICIES = '''
from uqdrive.policy.interface import Action


class Straight:
    """Never steers: the wind takes it off the road."""

    needs_camera = False

    def reset(self, seed):
        pass

    def act(self, frame, info):
        return Action(0.0)
'''
RULE = 'off_road=abs(car.y) > self.options["half_width"]'
WORLD = (
    "gym_world=uqdrive_roundabout",
    f"gym_world.env_id={PACKAGE}.envs:{PACKAGE}/Drift-v0",
    f"gym_world.hooks={PACKAGE}.hooks:DriftHooks",
    "gym_world.name=drift",
    "gym_world.horizon_steps=30",
)
EXPERIMENT = ("experiment=highway_roundabout", "experiment.name=drift", "experiment.scenarios=[drift]")


@pytest.fixture
def drift(tmp_path, monkeypatch) -> Path:
    """The user's package, importable for this test only; returns its folder."""
    folder = tmp_path / "site" / PACKAGE
    folder.mkdir(parents=True)
    for name, text in {"__init__": "", "envs": ENVS, "hooks": readme_hooks(), "policies": POLICIES}.items():
        (folder / f"{name}.py").write_text(textwrap.dedent(text))
    monkeypatch.syspath_prepend(str(folder.parent))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    yield folder
    forget()


def forget() -> None:
    """Drop the package's modules, so an edited file is imported afresh (as the next process would)."""
    for name in [n for n in sys.modules if n.startswith(PACKAGE)]:
        del sys.modules[name]


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, (path.name, old)
    path.write_text(text.replace(old, new))
    forget()


def refuse(token: str):
    raise AssertionError(f"{token} in a metrics file: JSON has none")


def certify(stage_config, tmp_path, *overrides: str):
    policy = tmp_path / "straight.yaml"
    policy.write_text(f"policy:\n  _target_: {PACKAGE}.policies.Straight\n")
    settings = (
        "certify.eta=0.5",
        "certify.look_size=4",
        "certify.budget=8",
        "executor.workers=1",
        "certify.ledger=false",
    )
    # fixed seeds, no ledger: the edits below are new cells on the same seeds, not new attempts spending gamma
    return run_certify(stage_config("certify", *WORLD, f"certify.policy={policy}", *settings, *overrides))


@pytest.mark.slow
def test_a_new_family_is_collected_trained_and_certified_by_config_and_an_edited_safe_set_reruns(
    drift, stage_config, tmp_path
):
    collection = run_collect(stage_config("collect", *WORLD, "collect.workers=1", "collect.episodes=4"))
    assert (collection.episodes, collection.frames) == (4, 4 * 30)
    run_preprocess(stage_config("preprocess", *EXPERIMENT))
    run_train(stage_config("train", *EXPERIMENT, "model=mcd"))
    cell = run_safety(stage_config("safety", *WORLD, *EXPERIMENT, "model=mcd", "executor.workers=1"))
    assert not cell.reused and cell.cell.location == "drift" and len(cell.cell.outcomes) == 4
    assert run_safety(stage_config("safety", *WORLD, *EXPERIMENT, "model=mcd", "executor.workers=1")).reused
    (saved,) = (tmp_path / "metrics/safety").glob("*drift*.json")
    assert json.loads(saved.read_text(), parse_constant=refuse)["max_corridor_use"] is None  # no corridor: null

    refuted = certify(stage_config, tmp_path)
    assert (refuted.verdict, refuted.outcomes) == ("refuted", "0" * 8)  # the wind takes a straight car off the road
    assert certify(stage_config, tmp_path).reused
    edit(drift / "hooks.py", RULE, "off_road=False")  # the user's safe-set rule edited: never off the road
    never_off = certify(stage_config, tmp_path)
    assert not never_off.reused and never_off.cell_key != refuted.cell_key
    assert (never_off.verdict, never_off.outcomes) == ("certified", "1" * 8)  # the edited rule's true answer
    again = run_safety(stage_config("safety", *WORLD, *EXPERIMENT, "model=mcd", "executor.workers=1"))
    assert not again.reused and again.cell.outcomes == "1111"

    edit(drift / "envs.py", "+ 0.1 +", "+ 0.0 +")  # the env's module edited: a new cell too
    assert not certify(stage_config, tmp_path).reused
    edit(drift / "policies.py", "Action(0.0)", "Action(0.0, speed=5.0)")  # and the policy's class
    assert not certify(stage_config, tmp_path).reused


def test_a_hooks_option_it_does_not_know_is_refused_before_any_work(drift, stage_config, tmp_path):
    with pytest.raises(ConfigError) as err:
        certify(stage_config, tmp_path, "++gym_world.hooks_options.destination=nxs")
    known = "not an option of DriftHooks (known: half_width)"
    assert str(err.value) == f"gym_world.hooks_options.destination='nxs': {known}"
    assert not (tmp_path / "cache").exists()


@pytest.mark.parametrize(
    ("hooks", "message"),
    [
        (f"{PACKAGE}.nowhere:Hooks", f"gym_world.hooks='{PACKAGE}.nowhere:Hooks' needs '{PACKAGE}.nowhere'"),
        (f"{PACKAGE}.hooks:Nope", f"gym_world.hooks='{PACKAGE}.hooks:Nope': module {PACKAGE}.hooks has no Nope"),
        (
            f"{PACKAGE}.policies:Straight",
            f"gym_world.hooks='{PACKAGE}.policies:Straight': expected info, highway or native, or module:Class "
            f"(a subclass of uqdrive.sim.gym_hooks.WorldHooks), got <class '{PACKAGE}.policies.Straight'>",
        ),
        ("drift", "gym_world.hooks='drift': expected info, highway or native, or module:Class"),
    ],
)
def test_hooks_that_cannot_be_loaded_are_refused_in_one_line(drift, stage_config, tmp_path, hooks, message):
    with pytest.raises(ConfigError) as err:
        certify(stage_config, tmp_path, f"gym_world.hooks={hooks}")
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_a_world_without_an_expert_is_certified_but_not_collected_in(drift, stage_config, tmp_path):
    edit(drift / "hooks.py", "    def expert(self):", "    def _expert(self):")
    with pytest.raises(ConfigError) as err:
        run_collect(stage_config("collect", *WORLD))
    assert str(err.value).startswith(f"gym_world.hooks='{PACKAGE}.hooks:DriftHooks': {PACKAGE}.envs:")
    assert "has no expert these hooks know of, so no frames to label" in str(err.value)
    assert certify(stage_config, tmp_path).verdict == "refuted"


def test_a_bug_in_the_users_hooks_is_one_line_with_the_seed_and_step(drift, stage_config, tmp_path):
    line = "        car = self.env.unwrapped\n"
    edit(drift / "hooks.py", line, f"{line}        1 / (car.x < 2)\n")  # raises from step 5 (x = 0.4 a step)
    with pytest.raises(WorldFailure) as err:
        certify(stage_config, tmp_path, "certify.base_seed=40")
    assert str(err.value) == (
        f"gym_world.hooks='{PACKAGE}.hooks:DriftHooks' raised ZeroDivisionError in state() at seed 40, step 5: "
        "division by zero"
    )
