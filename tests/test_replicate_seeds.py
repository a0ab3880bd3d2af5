"""Replicates drive disjoint rollout-seed blocks: no two replicates share a world, so their paired tables are
independent (what the stratified exact test and the t-test across replicates assume), while within a replicate
every cell of a stage drives the same seeds (so its cells pair by seed)."""

import pytest

from uqdrive.avoid.plan import AvoidStage
from uqdrive.safety.plan import SafetyStage
from uqdrive.schema import validate
from uqdrive.stage_schemas import SEED_BLOCK

REPLICATES = (0, 1, 7)


def safety_seeds(stage_config, seed: int, *overrides: str) -> range:
    stage = validate(SafetyStage, stage_config("safety", f"seed={seed}", *overrides))
    estimator = stage.estimator
    return range(estimator.base_seed, estimator.base_seed + estimator.planned_rollouts())


def avoid_seeds(stage_config, seed: int, profile: str) -> list[range]:
    # the fresh-seed check's controller count is read from params.yaml, which tmp_path lacks
    overrides = (f"seed={seed}", f"profile={profile}", "avoid.calibration.fresh_check.controllers=30")
    stage = validate(AvoidStage, stage_config("avoid", *overrides))
    most = max(stage.avoid.estimator.planned_rollouts(), stage.avoid.min_rollouts)
    return [
        range(stage.rollout_seeds(base), stage.rollout_seeds(base) + most)
        for base in (
            stage.avoid.base_seed,
            stage.avoid.validation_seed,
        )
    ]


def disjoint(ranges: list[range]) -> bool:
    spans = sorted((r.start, r.stop) for r in ranges)
    return all(stop <= start for (_, stop), (start, _) in zip(spans, spans[1:]))


@pytest.mark.parametrize("profile", ["tiny", "quick", "paper"])
def test_every_replicate_drives_its_own_block_of_worlds(stage_config, profile):
    safety = [safety_seeds(stage_config, r, f"profile={profile}") for r in REPLICATES]
    avoid = [block for r in REPLICATES for block in avoid_seeds(stage_config, r, profile)]
    assert disjoint(safety) and disjoint(avoid)
    assert all(len(block) < SEED_BLOCK for block in safety + avoid)
    assert safety[0].start == 100000 and safety[1].start == 100000 + SEED_BLOCK  # replicate 0 keeps its seeds


def test_the_cells_of_one_replicate_pair_by_seed(stage_config):
    """Every method, weather, noise and location of replicate r drives the same seeds."""
    cells = [("model=mcd", "weather=rain"), ("model=vi", "noise=0.1"), ("model=hmc", "scenario=roundabout_large")]
    assert len({safety_seeds(stage_config, 1, *cell) for cell in cells}) == 1
