"""The unknown conditions as one mixture cell (avoid.unknown_as=mixture): each rollout's variant is drawn from its
seed, uniformly and independently; rollout i of the mixture is rollout i of its variant's own cell; every cell runs
avoid.min_rollouts whatever its estimator reads."""

import itertools
import json

import numpy as np
import pytest
from scipy import stats

from uqdrive.avoid.plan import KNOWN, UNKNOWN, build_settings
from uqdrive.avoid.results import Mode
from uqdrive.pipeline.avoid_stage import run_avoid
from uqdrive.safety.executors import LockstepJob
from uqdrive.sim.condition import variant_of

VAN = "{name: van, weather: '${weather.name}', scenario: {obstacle_size: [5.2, 2.0, 2.2]}}"
TWO_UNKNOWN = f"avoid.unknown=[{{name: fog, weather: fog}},{VAN}]"


def _within_exact_band(counts: np.ndarray, n: int, p: float, alpha: float) -> bool:
    """Every count inside the two-sided exact binomial band of level 1 − alpha (Bonferroni over the counts)."""
    low, high = stats.binom.ppf(alpha / (2 * counts.size), n, p), stats.binom.isf(alpha / (2 * counts.size), n, p)
    return bool(np.all((counts >= low) & (counts <= high)))


def test_variants_are_drawn_uniformly_and_independently_of_the_neighbouring_seed():
    seeds = np.arange(200000, 208000)
    drawn = np.array([variant_of(int(s), 4) for s in seeds])
    assert set(drawn) == {0, 1, 2, 3}
    assert _within_exact_band(np.bincount(drawn, minlength=4), len(drawn), 1 / 4, 1e-3)
    pairs = np.bincount(4 * drawn[:-1] + drawn[1:], minlength=16)  # consecutive seeds: 16 equally likely pairs
    assert _within_exact_band(pairs, len(drawn) - 1, 1 / 16, 1e-3)
    assert variant_of(200000, 4) == variant_of(200000, 4)  # from the seed alone
    favoured = np.bincount(np.minimum(np.arange(8000) % 5, 3), minlength=4)  # the band rejects a rule favouring one
    assert not _within_exact_band(favoured, 8000, 1 / 4, 1e-3)


def test_mixture_rollout_i_is_rollout_i_of_its_variants_own_cell(avoid_config):
    mixture = build_settings(avoid_config("model=mcd", TWO_UNKNOWN, "avoid.unknown_as=mixture"))
    cells = build_settings(avoid_config("model=mcd", TWO_UNKNOWN))
    assert [c.name for c in mixture.conditions] == [KNOWN, UNKNOWN]
    job = mixture.job(mixture.unknown[0], None, 200000)
    indices = list(range(6))
    drawn = [job.where.variant(job.base_seed + i) for i in indices]
    assert len(set(drawn)) == 2, "the seeds should reach both variants"
    worker = LockstepJob(job, 3).worker()
    together = worker.run(indices)
    worker.close()
    for variant, condition in enumerate(cells.unknown):
        own = LockstepJob(cells.job(condition, None, 200000), 2).worker()
        mine = [i for i in indices if drawn[i] == variant]
        for i, alone in zip(mine, own.run(mine)):
            assert together[i].summary() == alone.summary()
            np.testing.assert_array_equal(together[i].x, alone.x)
            np.testing.assert_array_equal(together[i].eta2, alone.eta2)
        own.close()


@pytest.mark.slow
def test_the_mixture_stage_runs_every_cell_to_its_floor_and_reports_the_mixture_cell(avoid_config, tmp_path):
    result = run_avoid(avoid_config("model=mcd", TWO_UNKNOWN, "avoid.unknown_as=mixture", "avoid.min_rollouts=6"))
    saved = json.loads((tmp_path / "metrics/avoid/mcd-seed0.json").read_text())
    assert saved["conditions"] == [KNOWN, UNKNOWN] and result.conditions == [KNOWN, UNKNOWN]
    for condition, mode in itertools.product(saved["conditions"], Mode):
        cell = saved["cells"][condition][mode]
        # the estimator (chernoff_n(0.7, 0.05) = 4) reads 4; the cell runs 6, the sample the pairs use
        assert cell["n"] == 4 and len(cell["outcomes"]) == 6 and cell["fixed_rollouts"] == 6
    assert saved["calibration"]["certificate"]["calibration_runs"] == {KNOWN: 6, UNKNOWN: 6}
    for mode in Mode:
        mixture, cell = saved["unknown"][mode], saved["cells"][UNKNOWN][mode]
        assert (mixture["eta1"], mixture["eta1_low"], mixture["n"]) == (cell["eta1"], cell["eta1_low"], 4)
        assert set(mixture["variants"]) == {"fog", "van"}
        assert sum(v["runs"] for v in mixture["variants"].values()) == 6
        assert sum(v["safe"] for v in mixture["variants"].values()) == cell["outcomes"].count("1")
    base = {mode: saved["cells"][UNKNOWN][mode]["base_seed"] for mode in Mode}
    shares = {mode: {k: v["runs"] for k, v in saved["unknown"][mode]["variants"].items()} for mode in Mode}
    assert shares["off"] == shares["on"] and base["off"] == base["on"]  # the same seeds drive the same variants
