"""The Bayesian controller: live frame → π(o), η2, mutual information, with its draws from the episode's seed."""

import numpy as np
import pytest
import torch
from conftest import CONF

from uqdrive.data.binning import SteeringBins
from uqdrive.models import load_posterior
from uqdrive.network_input import preprocess_frame
from uqdrive.policy.controller import Controller
from uqdrive.sim import DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.sim.condition import Condition
from uqdrive.uq import decision_confidence, frame_measures


@pytest.fixture(scope="module")
def frame():
    with DrivingEnv() as env:
        scenario = ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout.yaml")
        return env.reset(3, Condition(scenario, WeatherConfig.from_yaml(CONF / "weather" / "rain.yaml"), 0.05))


def test_command_is_the_predictive_mode_with_its_uncertainty(random_models, frame):
    bins = SteeringBins()
    posterior = load_posterior(random_models["vi"], expected_method="vi", expected_classes=bins)
    controller = Controller(posterior, bins, 50, 0.1, 5.5)
    controller.reset(7)
    command = controller.act(frame, {})
    assert command.speed == 5.5
    assert np.isclose(bins.centres, command.steer).any()
    assert 0 < command.eta2 <= 1 and command.mutual_information >= 0 and command.entropy > 0
    # the same seed gives the same draws; the result is what uq computes from them: π(o) and MI
    # from the first 50 draws, η2 around that π(o) from 50 separate ones
    x = torch.from_numpy(preprocess_frame(frame)).float().div(255)[None, None]
    probs = posterior.sample_probs(x, 100, torch.Generator().manual_seed(7))
    expected = frame_measures(probs[:50], bins.centres, 0.1)
    assert command.steer == pytest.approx(float(expected.decision[0]))
    eta2 = decision_confidence(probs[50:], bins.centres, 0.1, expected.decision)
    assert command.eta2 == pytest.approx(float(eta2[0]))
    assert command.mutual_information == pytest.approx(float(expected.mutual_information[0]), abs=1e-6)
    controller.reset(7)
    assert controller.act(frame, {}) == command


def test_acting_without_a_frame_is_an_error(random_models):  # its settings are checked by the stage's schema
    posterior = load_posterior(random_models["mcd"])
    with pytest.raises(ValueError, match="camera frame"):
        Controller(posterior, SteeringBins(), 10, 0.1, 5.0).act(None, {})
