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


@pytest.mark.parametrize(("steer", "cls"), [(0.0, 10), (0.04, 10), (0.06, 11), (-0.06, 9), (1.0, 20), (-1.0, 0),
                                            (0.55, 16), (1.7, 20), (-3.0, 0)])
def test_nearest_centre_and_saturation(steer, cls):
    assert SteeringBins().to_class(steer) == cls


def test_other_resolutions_keep_the_same_contract():
    bins = SteeringBins(per_unit=5, max_abs=1.0)
    assert bins.num_classes == 11
    np.testing.assert_array_equal(bins.to_class(bins.centres), np.arange(11))


@pytest.mark.parametrize(("kwargs", "key"), [({"per_unit": 0}, "per_unit"), ({"max_abs": -1.0}, "max_abs"),
                                             ({"max_abs": 0.95}, "max_abs")])
def test_bad_bins_name_the_key(kwargs, key):
    with pytest.raises(ValueError, match=key):
        SteeringBins(**kwargs)


def test_bad_steering_and_class_values_are_rejected():
    bins = SteeringBins()
    with pytest.raises(ValueError, match="NaN"):
        bins.to_class([0.1, np.nan])
    with pytest.raises(ValueError, match="out of range"):
        bins.to_steering([21])
