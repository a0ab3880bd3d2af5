"""A cell's estimators of η1 as objects behind one interface (`CellEstimator`), chosen once by name from a config
(`cell_estimator`): ``chernoff`` and ``clopper_pearson`` run a sample whose size is fixed by (θ, γ) and bound its
mean; ``sequential`` looks every ``look_size`` outcomes and stops when its calibrated rule allows
(`uqdrive.uq.sequential`). Each says how many outcomes it may take (``most``), how many it always takes
(``least``), and reads its estimate from outcomes pulled in index order; the `Estimate` it returns records its
name as its ``scheme``. No code outside this module asks which one it has."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from uqdrive.uq.bounds import chernoff_n, clopper_pearson_n
from uqdrive.uq.estimators import Draw, Estimate, chernoff, clopper_pearson, sequential
from uqdrive.uq.sequential import sequential_scheme


class CellEstimator(Protocol):
    """An estimator of a cell's η1 with P(|η̂1 − η1| > θ) ≤ γ."""

    name: str

    def most(self, theta: float, gamma: float, look_size: int) -> int:
        """Outcomes it may take at most."""

    def least(self, theta: float, gamma: float, look_size: int) -> int:
        """Outcomes it takes whatever they are (a sample whose size was fixed in advance)."""

    def estimate(self, draw: Draw, theta: float, gamma: float, look_size: int) -> Estimate:
        """η̂1 from outcomes ``draw(count)`` pulls in index order, as many as it asks for."""


@dataclass(frozen=True)
class FixedSample:
    """n outcomes, n fixed by (θ, γ) (``size``), bounded at once (``bound``)."""

    name: str
    size: Callable[[float, float], int]
    bound: Callable[[int, int, float, float], Estimate]

    def most(self, theta: float, gamma: float, look_size: int) -> int:
        return self.size(theta, gamma)

    def least(self, theta: float, gamma: float, look_size: int) -> int:
        return self.size(theta, gamma)

    def estimate(self, draw: Draw, theta: float, gamma: float, look_size: int) -> Estimate:
        n = self.size(theta, gamma)
        return self.bound(int(draw(n).sum()), n, theta, gamma)


@dataclass(frozen=True)
class SequentialSample:
    """Looks of ``look_size`` outcomes until the calibrated rule stops (`uqdrive.uq.estimators.sequential`)."""

    name: str = "sequential"

    def most(self, theta: float, gamma: float, look_size: int) -> int:
        return sequential_scheme(theta, gamma, look_size).max_n

    def least(self, theta: float, gamma: float, look_size: int) -> int:
        return int(sequential_scheme(theta, gamma, look_size).stop_points[0].min())

    def estimate(self, draw: Draw, theta: float, gamma: float, look_size: int) -> Estimate:
        return sequential(draw, theta, gamma, look_size)


CELL_ESTIMATORS: dict[str, CellEstimator] = {
    e.name: e
    for e in (
        FixedSample("chernoff", chernoff_n, chernoff),
        FixedSample("clopper_pearson", clopper_pearson_n, clopper_pearson),
        SequentialSample(),
    )
}


def cell_estimator(name: str) -> CellEstimator:
    """The estimator a config's ``scheme`` names (one of `CELL_ESTIMATORS`)."""
    try:
        return CELL_ESTIMATORS[name]
    except KeyError:
        raise ValueError(f"scheme={name!r}: one of {', '.join(CELL_ESTIMATORS)}") from None
