"""The three-tier warning system: levels from η2 and MI, the actions (warning 2 stops the car and hands
over), its config."""

import numpy as np
import pytest
import torch
from conftest import CONF

from uqdrive.data.binning import SteeringBins
from uqdrive.models import load_posterior
from uqdrive.models.posterior import Posterior
from uqdrive.policy.controller import Controller
from uqdrive.policy.draws import DrawSettings
from uqdrive.policy.interface import NO_WARNING
from uqdrive.policy.warnings import (
    WarningAction,
    WarningActions,
    WarningConfig,
    WarningController,
    WarningRule,
    classify,
)
from uqdrive.safety.rollout import run_rollout
from uqdrive.safety.safe_sets import HANDOVER
from uqdrive.schema import ConfigError
from uqdrive.sim import DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.sim.condition import Condition
from uqdrive.uq import chernoff_n

BINS = SteeringBins()
FAST = WarningConfig(theta=0.3)  # 21 draws per frame; the paper's thresholds and actions


class FixedPosterior:
    """Hand-made posterior samples: the same [n, C] class probabilities for every frame (repeated
    when more draws are asked for: the controller draws π(o) and η2 separately)."""

    def __init__(self, probs: np.ndarray):
        self.probs = torch.as_tensor(probs, dtype=torch.float32)

    def eval(self) -> "FixedPosterior":
        return self

    def features_each(self, x: torch.Tensor) -> torch.Tensor:
        return x.flatten(1)

    def head_probs(self, features: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        assert n % len(self.probs) == 0
        return self.probs.repeat(n // len(self.probs), 1)[:, None, :].expand(n, features.shape[0], -1)

    head_probs_each = Posterior.head_probs_each  # one head_probs call per frame, as every posterior can


def samples(classes: list[int]) -> np.ndarray:
    """One near-one-hot sample per entry of ``classes`` (0.98 on the class, the rest spread)."""
    probs = np.full((len(classes), BINS.num_classes), 0.02 / (BINS.num_classes - 1))
    probs[np.arange(len(classes)), classes] = 0.98
    return probs


CONFIDENT = samples([10] * FAST.samples)  # every draw: straight ahead
DISAGREEING = samples([0] * 11 + [20] * 10)  # full right against full left: η2 = 11/21


@pytest.fixture(scope="module")
def obstacle():
    return ScenarioConfig.from_yaml(CONF / "scenario" / "obstacle.yaml"), WeatherConfig.from_yaml(
        CONF / "weather" / "clear_noon.yaml"
    )


@pytest.fixture(scope="module")
def frame(obstacle):
    with DrivingEnv() as env:
        return env.reset(0, Condition(*obstacle))


def controller(probs: np.ndarray, config: WarningConfig = FAST) -> WarningController:
    rule = WarningRule(config, DrawSettings())
    return WarningController(FixedPosterior(probs), BINS, rule, eps=0.1, speed=8.0, control_hz=15.0)


def test_levels_follow_the_paper_thresholds():
    eta2 = np.array([1.0, 0.7, 1.0, 0.69, 0.6, 0.599, 0.0])
    mi = np.array([0.45, 0.0, 0.46, 2.0, 2.0, 0.0, 0.0])
    assert classify(eta2, mi, 0.7, 0.6, 0.45).tolist() == [NO_WARNING, NO_WARNING, 0, 1, 1, 2, 2]
    # thresholds broadcast against frames: the calibration classifies all candidates at once
    grid = classify(eta2[None], mi[None], np.array([[0.7], [1.0]]), np.array([[0.6], [0.0]]), 0.45)
    assert grid.shape == (2, 7) and grid[1].tolist() == [NO_WARNING, 1, 0, 1, 1, 1, 1]
    with pytest.raises(ValueError, match="finite"):
        classify(np.nan, 0.0, 0.7, 0.6, 0.45)


def test_confident_posterior_raises_no_warning_and_disagreeing_one_raises_warning_2(frame):
    calm = controller(CONFIDENT)
    calm.reset(0)
    command = calm.act(frame)
    assert (command.eta2, command.warning, command.speed, command.handover) == (1.0, NO_WARNING, 8.0, False)
    assert command.mutual_information == pytest.approx(0.0, abs=1e-5)

    torn = controller(DISAGREEING)
    torn.reset(0)
    command = torn.act(frame)
    assert command.eta2 == pytest.approx(11 / 21) and command.mutual_information > 0.6
    assert (command.warning, command.speed, command.alert, command.handover) == (2, 0.0, True, True)


def test_agreement_within_eps_with_high_mutual_information_is_warning_0(frame):
    split = samples([10] * 11 + [11] * 10)  # straight vs 0.1 left: every decision within ε of π(o)
    command = controller(split).act(frame)
    assert command.eta2 == 1.0 and command.mutual_information > 0.45
    assert (command.warning, command.speed, command.alert, command.handover) == (0, 4.0, False, False)


def test_slow_down_holds_then_releases_and_hand_over_latches():
    actions = WarningActions(FAST.actions, hold_frames=2)
    speeds = [actions.step(np.array(level))[0].item() for level in (0, -1, -1, -1, 1, -1)]
    assert speeds == [0.5, 0.5, 0.5, 1.0, 0.5, 0.5]
    outcomes = [actions.step(np.array(level)) for level in (2, -1, 0)]
    assert all(o[0] == 0.0 and o[2] for o in outcomes)  # warning 2: speed 0 until the run ends


def test_warning_2_brakes_the_car_to_a_stop_and_hands_over(obstacle):
    with DrivingEnv(control_hz=15.0, horizon_s=8.0) as env:
        result = run_rollout(env, controller(DISAGREEING), 5, Condition(*obstacle, 0.0))
        speed = env.trajectory["speed"]
    assert result.termination == HANDOVER and result.verdict.safe and not result.verdict.collision
    assert speed[-1] == 0.0 and np.all(np.diff(speed) <= 0)
    assert result.steps == int(np.ceil(8.0 / (6.0 / 15.0)))  # 8 m/s at the 6 m/s² brake limit
    assert set(result.warning.tolist()) == {2} and not result.command_speed.any()


def test_confident_controller_drives_at_full_speed_to_the_horizon(obstacle):
    with DrivingEnv(control_hz=15.0, horizon_s=1.0) as env:
        result = run_rollout(env, controller(CONFIDENT), 5, Condition(*obstacle, 0.0))
    # a 1 s horizon ends long before the obstacle: the run answered nothing, so it is not safe
    assert result.termination == "timeout" and not result.verdict.reached_goal and not result.verdict.safe
    assert set(result.warning.tolist()) == {NO_WARNING} and np.all(result.command_speed == 8.0)


def test_warnings_that_never_fire_leave_the_rollout_unchanged(random_models, obstacle):
    """The avoid stage reuses such warnings-off rollouts for the warnings-on cell: it must be exact."""
    posterior = load_posterior(random_models["vi"])
    never = WarningConfig(delta1=0.0, delta2=0.0, tau=10.0, theta=0.3)
    with DrivingEnv(horizon_s=1.5) as env:
        off = run_rollout(env, Controller(posterior, BINS, never.samples, 0.1, 8.0), 11, Condition(*obstacle, 0.05))
        rule = WarningRule(never, DrawSettings())
        on = run_rollout(env, WarningController(posterior, BINS, rule, 0.1, 8.0, 15.0), 11, Condition(*obstacle, 0.05))
    assert off.summary() == on.summary()
    for key in ("x", "y", "eta2", "mutual_information", "warning", "command_speed"):
        assert np.array_equal(getattr(off, key), getattr(on, key))


def test_defaults_are_the_papers_and_samples_come_from_chernoff():
    cfg = WarningConfig()
    assert (cfg.delta1, cfg.delta2, cfg.tau, cfg.samples) == (0.7, 0.6, 0.45, 738)
    assert [(a.speed, a.alert, a.handover) for a in cfg.actions] == [
        (0.5, False, False),
        (0.5, True, False),
        (0.0, True, True),
    ]
    assert WarningConfig(theta=0.1, gamma=0.01).samples == chernoff_n(0.1, 0.01)


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"delta1": 0.6, "delta2": 0.7}, "warning.delta2=0.7 must be <= delta1=0.6"),
        ({"delta1": 1.2}, "warning.delta1=1.2: input should be less than or equal to 1"),
        ({"delta2": -0.1}, "warning.delta2=-0.1: input should be greater than or equal to 0"),
        ({"tau": -0.5}, "warning.tau=-0.5: input should be greater than or equal to 0"),
        ({"tau": float("nan")}, "warning.tau=nan: input should be a finite number"),
        ({"theta": 0.0}, "warning.theta=0.0: input should be greater than 0"),
        ({"hold_s": "1s"}, "warning.hold_s='1s': input should be a valid number"),
        ({"actions": {"warning0": {"speed": 1.5}}}, "warning.actions.warning0.speed=1.5: input should be less than"),
        (
            {"actions": {"warning2": {"speed": 0.2, "handover": True}}},
            "warning.actions.warning2.speed=0.2 must be 0 when handover is true",
        ),
        ({"actions": {"warning2": {"speed": 0.0, "handover": "yes"}}}, "warning.actions.warning2.handover='yes'"),
        ({"delta3": 0.5}, "warning.delta3: unknown key; did you mean 'delta"),
        ({"actions": {"warning3": {"speed": 0.5}}}, "warning.actions.warning3: unknown key; did you mean 'warning2'?"),
    ],
)
def test_bad_warning_config_is_one_line_naming_key_value_and_what_is_allowed(values, message):
    with pytest.raises(ConfigError) as err:
        WarningConfig.from_config(values)
    assert str(err.value).startswith(message)
    assert "\n" not in str(err.value)


def test_from_config_reads_actions_and_fills_the_levels_it_does_not_name():
    cfg = WarningConfig.from_config(
        {"delta1": 0.8, "actions": {"warning0": {"speed": 0.25}, "warning1": {"speed": 0.5, "alert": True}}}
    )
    assert cfg.delta1 == 0.8 and cfg.actions[0] == WarningAction(0.25)
    assert cfg.actions[2] == WarningConfig().actions[2]  # the paper's hand-over
