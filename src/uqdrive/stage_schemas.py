"""What the stages' configs share (`uqdrive.schema`): the top level every stage has, the experiment, the executor,
a grid stage's sweep (an experiment's class set is data's: `data/experiment.py`; a stage that fits or drives a
posterior is models': `models/model_stage.py`).

Each stage's own schema lives in its wing (`CollectStage` in `sim/collect_plan.py`, `SafetyStage` in `safety/plan.py`,
…) and names the sections it reads; the values of a stage's own sections are written once, in its
conf/<stage>.yaml (its schema gives them no defaults), and the shared groups (scenario, weather, the car, warning,
model) take theirs from their dataclasses. The top level of a stage's config also holds the profile's keys for other
stages, so it ignores the keys it does not name; every section rejects unknown keys.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field

from uqdrive.schema import Bool, Count, MethodName, NonNegative, Seed, Str, schema

Names = tuple[Str, ...]
MethodNames = tuple[MethodName, ...]  # conf/model/<name>.yaml
Noises = tuple[NonNegative, ...]
NonEmptyNames = Annotated[Names, Field(min_length=1)]
NonEmptyMethodNames = Annotated[MethodNames, Field(min_length=1)]
NonEmptyNoises = Annotated[Noises, Field(min_length=1)]
NonEmptySeeds = Annotated[tuple[Seed, ...], Field(min_length=1)]  # training seeds: the replicates


def training_stage(experiment: str, method: str, gym: bool = False) -> str:
    """The DVC stage that trains ``experiment``'s ``method``, every replicate (MCD: the trunk the heads sit on).
    ``gym``: the experiment is a Gymnasium world's (named after it, `uqdrive.sim.config.names_gym_world`), trained in
    dvc.yaml's gym_ stages, which exist for the worlds params.yaml's gym_worlds lists; any other experiment trains in
    the pybullet stages, whatever world drives it."""
    stage = f"train_mcd@{experiment}" if method == "mcd" else f"train@{experiment}-{method}"
    return f"gym_{stage} (with {experiment} in params.yaml's gym_worlds)" if gym else stage


@schema
class ExecutorSettings:
    """conf/executor/: where rollouts run (a local process pool, or Ray actors at ``address``)."""

    name: Literal["process", "ray"]
    workers: Count
    address: Str | None = None  # ray: null starts a local Ray; "auto" or ray://host:port joins a cluster

    def options(self) -> dict[str, Any]:
        """The backend's own options (unset ones dropped)."""
        return {} if self.address is None else {"address": self.address}


@schema(root=True)
class Named:
    """A config group a stage reads only the name of (the stages that use the rest check it)."""

    name: Str


@schema
class Paths:
    """conf/common.yaml's `paths`: the project (inputs, the MLflow store) and where this run writes."""

    root: Str
    out: Str
    raw: Str
    processed: Str
    models: Str
    metrics: Str
    plots: Str


SEED_BLOCK = 1_000_000
"""Rollout seeds per training replicate. Replicate r drives seeds base + r·SEED_BLOCK + i, so no two replicates
share a world: their paired runs are independent, which the betting interval over the controllers (findings "for
these trained controllers") and the sign test and betting interval across replicates (method-level claims) need.
Within a replicate every cell drives the same seeds, so its methods, conditions and warnings modes pair by seed."""


@schema(root=True)
class Stage:
    """What every stage's config holds (conf/common.yaml)."""

    seed: Seed  # the training seed: the replicate
    replicate: Str  # its name (seed<seed>)
    progress: Bool
    paths: Paths

    def rollout_seeds(self, base: int) -> int:
        """The first rollout seed of this replicate's block for a stage whose replicate 0 starts at ``base``."""
        return base + self.seed * SEED_BLOCK


@schema
class Sweep:
    """The grid a one-process grid stage runs (params.yaml's lists)."""

    weathers: NonEmptyNames
    noises: NonEmptyNoises
    methods: MethodNames = ()
    replicates: tuple[Seed, ...] = ()  # training seeds
    locations: Names = ()


@schema(root=True)
class SafetyGrid(Stage):
    """The offline-safety sweep's cells, as a stage that reads them names them (params.yaml's lists)."""

    methods: NonEmptyNames
    replicates: NonEmptySeeds
    weathers: NonEmptyNames
    noises: NonEmptyNoises
    locations: NonEmptyNames
