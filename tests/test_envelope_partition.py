"""Phase two's regions cover the cube once, are finest along phase one's boundary, and share γ exactly."""

from fractions import Fraction

import numpy as np
import pytest

from uqdrive.envelope.partition import PartitionSettings, Region, partition
from uqdrive.envelope.search import BoundaryModel
from uqdrive.schema import ConfigError, validate
from uqdrive.uq.multiplicity import split_gamma

TAU = 0.9


def step_model(dim: int) -> BoundaryModel:
    """A posterior from many rollouts: always safe where u0 < 0.3, never where u0 >= 0.3."""
    points = np.random.default_rng(3).random((2000, dim))
    return BoundaryModel(points, (points[:, 0] < 0.3).astype(int), TAU, bandwidth=0.03)


@pytest.mark.parametrize("dim", [2, 3])
def test_regions_cover_the_cube_once_and_are_finest_along_the_boundary(dim):
    settings = PartitionSettings(min_depth=1, max_depth=3)
    regions = partition(step_model(dim), dim, settings)
    assert sum(r.volume for r in regions) == pytest.approx(1.0)
    inside = np.stack([r.contains(np.random.default_rng(5).random((4000, dim))) for r in regions])
    assert (inside.sum(0) == 1).all()
    edges = np.array([[1.0] * dim])
    assert np.stack([r.contains(edges) for r in regions]).sum() == 1  # the cube's far corner belongs to one region
    for r in regions:
        if r.low[0] < 0.3 < r.high[0]:
            assert r.depth == settings.max_depth, r
        if r.depth > settings.min_depth:  # split from a parent box that reaches within 0.1 of the boundary
            parent = Region.cube(dim)
            for child in r.path[:-1]:
                parent = parent.children()[child]
            assert parent.low[0] < 0.4 and parent.high[0] > 0.2, r
    assert len(regions) < 2 ** (settings.max_depth * dim) / 2
    assert len({r.name for r in regions}) == len(regions)


def test_region_points_and_children():
    r = Region((0.0, 0.5), (0.5, 1.0), (2,))
    assert r.depth == 1 and r.volume == 0.25 and r.name == "r2"
    children = r.children()
    assert [c.path for c in children] == [(2, 0), (2, 1), (2, 2), (2, 3)]
    assert children[1].low == (0.25, 0.5) and children[1].high == (0.5, 0.75)  # bit 0: the upper half of axis 0
    assert r.at(np.array([[0.5, 0.5]])).tolist() == [[0.25, 0.75]]
    assert r.grid(1).tolist() == [[0.0, 0.5], [0.0, 1.0], [0.5, 0.5], [0.5, 1.0]]


def test_depth_settings_are_checked():
    with pytest.raises(ConfigError, match=r"^partition.min_depth=4 must be <= max_depth \(3\)$"):
        validate(PartitionSettings, {"min_depth": 4, "max_depth": 3}, "partition")
    with pytest.raises(ConfigError, match=r"^partition.max_depth=6: input should be less than or equal to 5"):
        validate(PartitionSettings, {"max_depth": 6}, "partition")


@pytest.mark.parametrize("gamma", [0.05, 0.1, 0.01, 1 / 3, 0.07])
def test_gamma_shares_are_equal_and_their_exact_sum_is_at_most_gamma(gamma):
    for count in [*range(1, 80), 97, 128, 255, 1000, 4096]:
        shares = (split_gamma(gamma, count),) * count
        assert len(shares) == count and len(set(shares)) == 1
        assert sum(map(Fraction, shares)) <= Fraction(gamma)
        assert shares[0] >= gamma / count * (1 - 1e-15)  # nothing given away beyond rounding
