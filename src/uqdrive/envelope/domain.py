"""The operating domain as a distribution: a density over the envelope's condition space, so that "η1 over the
domain" (a rollout's condition drawn from it) is an estimand, refuted or certified by `uqdrive.uq.rare`.

The axes are the envelope's (`uqdrive.envelope.space`: same keys, ranges and checks); each domain axis adds a
Beta(a, b) law over its own range. The proposal of a rare-event search spans the condition space's whole box,
so a domain narrower than the box (density zero where the proposal puts mass) fails before any rollout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uqdrive.envelope.space import AxisSettings, ConditionSpace
from uqdrive.schema import Bool, ConfigError, Positive, Seed, Str, schema
from uqdrive.sim.condition import Condition
from uqdrive.uq.rare import FailureRecord, RareSettings
from uqdrive.uq.rare_proposal import ProductBeta


@schema(frozen=True)
class DomainAxisSettings(AxisSettings):
    """An envelope axis (key, range) with the Beta law its values are drawn from over that range (``shape``:
    (a, b); (1, 1) is uniform)."""

    shape: tuple[Positive, Positive] = (1.0, 1.0)


@schema(frozen=True)
class DomainSettings:
    """The domain: one law per axis of the condition space, in any order, each axis of the space named once."""

    axes: tuple[DomainAxisSettings, ...]


@schema(frozen=True, kw_only=True)
class RareSection(RareSettings):
    """conf/rare.yaml's `rare`: the domain's Beta law per envelope axis (``shapes``: key → (a, b); uniform where
    not named), the claim and its settings (`RareSettings`), whether to ``certify`` too, the conditions' random
    stream (``seed``), the first rollout seed and the outputs."""

    shapes: dict[Str, tuple[Positive, Positive]] | None = None
    certify: Bool = False
    seed: Seed = 0
    base_seed: Seed
    out: Str
    rollout_log: Str


@dataclass(frozen=True)
class Domain:
    """The density over ``space``'s unit cube (``nominal``) and the map from a point to its world."""

    space: ConditionSpace
    nominal: ProductBeta

    @classmethod
    def of(cls, settings: DomainSettings, space: ConditionSpace) -> Domain:
        """The domain over ``space``; one line naming the key and value if an axis is unknown, missing, or does
        not span its space axis's range."""
        by_key = {a.key: (i, a) for i, a in enumerate(settings.axes)}
        if len(by_key) != len(settings.axes) or set(by_key) != set(space.names):
            raise ConfigError(
                f"domain.axes: keys {[a.key for a in settings.axes]} must be the condition space's "
                f"axes {list(space.names)}, each once"
            )
        a, b, low, high = [], [], [], []
        for axis in space.axes:
            i, own = by_key[axis.key]
            width = axis.high - axis.low
            lo, hi = (own.range[0] - axis.low) / width, (own.range[1] - axis.low) / width
            if lo < -1e-12 or hi > 1 + 1e-12:
                raise ConfigError(
                    f"domain.axes[{i}].range={list(own.range)}: reaches outside {axis.key}'s "
                    f"[{axis.low:g}, {axis.high:g}], where no rollout of the condition space can go"
                )
            if lo > 1e-12 or hi < 1 - 1e-12:
                raise ConfigError(
                    f"domain.axes[{i}].range={list(own.range)}: the density is zero on part of {axis.key}'s "
                    f"[{axis.low:g}, {axis.high:g}], where the proposal puts mass; give the domain the space's range"
                )
            a.append(own.shape[0])
            b.append(own.shape[1])
            low.append(0.0)
            high.append(1.0)
        return cls(space, ProductBeta.of(a, b, low, high))

    @classmethod
    def over(cls, space: ConditionSpace, shapes: dict[str, tuple[float, float]]) -> Domain:
        """The domain over all of ``space``'s box with these Beta shapes (key → (a, b); uniform where unnamed)."""
        for key in shapes:
            if key not in space.names:
                raise ConfigError(f"rare.shapes.{key}: not an axis of envelope.axes {list(space.names)}")
        axes = [
            {"key": a.key, "range": [a.low, a.high], "shape": list(shapes.get(a.key, (1.0, 1.0)))} for a in space.axes
        ]
        return cls.of(DomainSettings(axes=tuple(DomainAxisSettings(**a) for a in axes)), space)

    def condition(self, point) -> Condition:
        """The world at a point of the unit cube (checked by the schemas)."""
        return self.space.condition(tuple(float(u) for u in point))

    def replay(self, record: FailureRecord) -> tuple[int, Condition]:
        """A failure's seed and world, to re-drive it."""
        return record.seed, self.condition(record.point)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n points of the unit cube drawn from the domain ([n, d])."""
        return self.nominal.sample(rng, 1, n)[0]
