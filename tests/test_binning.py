import numpy as np
import pytest

from uqdrive.data.binning import SteeringBins


def test_tenths_give_21_centres_with_straight_ahead_in_the_middle():
    bins = SteeringBins()
    assert bins.num_classes == 21
    np.testing.assert_allclose(bins.centres, np.round(np.arange(-10, 11) / 10, 10))
    assert bins.centres[10] == 0.0


def test_class_to_steering_to_class_round_trips_exactly():
    bins = SteeringBins()
    classes = np.arange(bins.num_classes)
    np.testing.assert_array_equal(bins.to_class(bins.to_steering(classes)), classes)


def test_steering_to_class_to_steering_is_within_half_a_tenth():
    bins = SteeringBins()
    steering = np.random.default_rng(0).uniform(-1, 1, 10_000)
    decoded = bins.to_steering(bins.to_class(steering))
    assert np.max(np.abs(decoded - steering)) <= 0.05 + 1e-12


@pytest.mark.parametrize(
    ("steer", "cls"),
    [(0.0, 10), (0.04, 10), (0.06, 11), (-0.06, 9), (1.0, 20), (-1.0, 0), (0.55, 16), (1.7, 20), (-3.0, 0)],
)
def test_nearest_centre_and_saturation(steer, cls):
    assert SteeringBins().to_class(steer) == cls


def test_other_resolutions_keep_the_same_contract():
    bins = SteeringBins(per_unit=5)
    assert bins.num_classes == 11
    np.testing.assert_array_equal(bins.to_class(bins.centres), np.arange(11))


@pytest.mark.parametrize(("low", "high"), [(-0.5, 0.3), (-0.2, 0.8), (0.0, 0.1), (-1.0, 1.0)])
def test_an_experiments_class_set_round_trips_through_the_binning(low, high):
    bins = SteeringBins(low=low, high=high)
    assert bins.num_classes == round((high - low) * 10) + 1
    np.testing.assert_allclose(bins.centres[[0, -1]], [low, high], atol=1e-12)
    classes = np.arange(bins.num_classes)
    np.testing.assert_array_equal(bins.to_class(bins.to_steering(classes)), classes)
    assert SteeringBins.from_dict(bins.to_dict()) == bins
    inside = np.random.default_rng(1).uniform(low - 0.049, high + 0.049, 5000)
    assert np.max(np.abs(bins.to_steering(bins.to_class(inside)) - inside)) <= 0.05 + 1e-12
    assert not bins.clipped(inside).any()
    beyond = np.array([low - 0.06, high + 0.06])
    assert bins.clipped(beyond).all()
    np.testing.assert_array_equal(bins.to_class(beyond), [0, bins.num_classes - 1])


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"per_unit": 0}, "per_unit"),
        ({"low": -1.5}, "low"),
        ({"high": 0.95}, "high"),
        ({"low": 0.5, "high": 0.5}, "low"),
    ],
)
def test_bad_bins_name_the_key(kwargs, key):
    with pytest.raises(ValueError, match=key):
        SteeringBins(**kwargs)


def test_bad_steering_and_class_values_are_rejected():
    bins = SteeringBins()
    with pytest.raises(ValueError, match="NaN"):
        bins.to_class([0.1, np.nan])
    with pytest.raises(ValueError, match="out of range"):
        bins.to_steering([21])
