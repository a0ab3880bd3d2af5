"""The findings stage: the family of paired comparisons over replicates, each for the average over these controllers,
Bonferroni over the family."""

import dataclasses

import numpy as np
import pytest
from test_report import METHODS, N, avoid_result, safety_cell

from uqdrive.pipeline.findings_stage import avoid_comparisons, decide, safety_comparisons

TRAINING = ("roundabout", "clear_noon", 0.0)


def with_outcomes(cell, safe: str):
    estimate = dataclasses.replace(cell.estimate, value=safe.count("1") / N)
    return dataclasses.replace(cell, outcomes=safe, estimate=estimate)


def cells_where(rain: dict[int, tuple[str, str]]) -> list:
    """mcd and vi at the training condition (always safe) and in rain, with given rain outcomes per replicate."""
    rng = np.random.default_rng(0)
    cells = []
    for seed, (mcd, vi) in rain.items():
        for method, safe in (("mcd", mcd), ("vi", vi)):
            cells.append(with_outcomes(safety_cell(rng, method, seed, *TRAINING), "1" * N))
            cells.append(with_outcomes(safety_cell(rng, method, seed, "roundabout", "rain", 0.0), safe))
    return cells


def named(findings, name: str):
    return next(f.finding for f in findings.findings if f.finding.name == name)


def test_an_average_gain_over_the_controllers_is_supported_and_one_that_cancels_is_not():
    good, bad = "1" * N, "0" * 12 + "1" * 7
    agree = cells_where({0: (good, bad), 1: (good, bad), 2: (good, bad)})
    findings = decide(list(safety_comparisons(agree, list(METHODS), TRAINING)), 0.05)
    rain = named(findings, "mcd vs vi at roundabout-rain-noise0.0")
    assert rain.supported and rain.effect == pytest.approx(12 / N) and rain.low > 0 and rain.runs == N
    assert rain.a_only == {0: 12, 1: 12, 2: 12} and rain.b_only == {0: 0, 1: 0, 2: 0} and rain.replicates == (0, 1, 2)
    assert rain.level == pytest.approx(0.05 / findings.comparisons) and rain.p_value <= rain.level
    assert named(findings, "vi: roundabout-rain-noise0.0 vs the training condition").supported
    assert not named(findings, "mcd: roundabout-rain-noise0.0 vs the training condition").supported  # both safe
    # one controller gains what the other loses: no gain on average over these controllers, nothing supported
    cancel = cells_where({0: (good, bad), 1: (bad, good)})
    findings = decide(list(safety_comparisons(cancel, list(METHODS), TRAINING)), 0.05)
    rain = named(findings, "mcd vs vi at roundabout-rain-noise0.0")
    assert not rain.supported and rain.effect == 0 and rain.low < 0 < rain.high
    # each method's rain is worse than the training condition on average (in one of its two controllers)
    assert findings.comparisons == 4 and findings.supported == 2


def test_without_the_training_condition_only_methods_are_compared():
    cells = [c for c in cells_where({0: ("1" * N, "1" * N)}) if c.weather == "rain"]
    family = list(safety_comparisons(cells, list(METHODS), TRAINING))
    assert [kind for _, kind, *_ in family] == ["method"]


def test_avoid_pairs_warnings_with_the_same_seeds_and_refuses_unpaired_cells():
    rng = np.random.default_rng(1)
    results = [avoid_result(rng, m, r) for m in METHODS for r in (0, 1)]
    family = list(avoid_comparisons(results, list(METHODS)))
    names = [c.name for *_, c in family]
    assert "mcd: on vs off at fog" in names and "vi: calibrated vs fresh_off at known" in names
    assert "mcd: fog vs known, warnings off" in names and "mcd vs vi at fog, warnings off" in names
    assert len(family) == 2 + 2 + 2 * 2 * 2  # methods per condition, conditions per method, two pairs per condition
    result = results[0]
    cell = dataclasses.replace(result.cells["fog"]["on"], base_seed=300000)  # "on" moved to the fresh seeds
    results[0] = dataclasses.replace(result, cells={**result.cells, "fog": {**result.cells["fog"], "on": cell}})
    with pytest.raises(ValueError, match="cells on other rollout seeds"):
        list(avoid_comparisons(results, list(METHODS)))


def test_redecide_gives_the_stages_claims_exactly_and_its_findings_from_the_counts(tmp_path):
    """`uqdrive redecide` on a findings file the stage wrote: every claim's numbers are the stage's (they read only
    the per-replicate differences); every comparison keeps its counts and average gain, its interval read from the
    runs laid out in a seeded order (valid, ends close to the stage's)."""
    import json

    from test_report import write_run

    from uqdrive.analysis.redecide import main, redecide

    findings = write_run(tmp_path)[3]
    path = tmp_path / "metrics/findings.json"
    again = redecide(json.loads(path.read_text()))
    assert [dataclasses.asdict(c) for c in again.claims] == [dataclasses.asdict(c) for c in findings.claims]
    assert again.comparisons == findings.comparisons and again.alpha == findings.alpha
    for old, new in ((o.finding, n.finding) for o, n in zip(findings.findings, again.findings)):
        assert (new.name, new.a_only, new.b_only, new.runs) == (old.name, old.a_only, old.b_only, old.runs)
        assert new.effect == pytest.approx(old.effect) and abs(new.low - old.low) < 0.2
    assert main([str(path), "--out", str(tmp_path / "again.json")]) == 0 and (tmp_path / "again.json").exists()


def test_a_replicate_missing_from_one_method_stops_the_claims_with_one_line(tmp_path):
    """vi lacks replicate 2 (offline) and mcd lacks replicate 1 (avoid): one line naming the method, the replicates
    and the experiment, before any claim is decided; a recorded claim whose sides do not pair, the same."""
    import json

    from uqdrive.analysis.method_claims import check_replicates
    from uqdrive.analysis.redecide import main
    from uqdrive.schema import ConfigError

    cells = [c for c in cells_where({0: ("1" * N,) * 2, 1: ("1" * N,) * 2, 2: ("1" * N,) * 2})]
    uneven = [c for c in cells if not (c.method == "vi" and c.replicate == 2)]
    with pytest.raises(ConfigError, match=r"^method claims, offline safety: replicates \[2\] of \[0, 1, 2\] missing"):
        check_replicates(uneven, [], list(METHODS))
    rng = np.random.default_rng(2)
    results = [avoid_result(rng, m, r) for m in METHODS for r in (0, 1) if (m, r) != ("mcd", 1)]
    with pytest.raises(ConfigError, match=r"collision avoidance: replicates \[1\] of \[0, 1\] missing from mcd"):
        check_replicates(cells, results, list(METHODS))
    check_replicates(cells, [], list(METHODS))  # the same replicates everywhere: nothing to say
    claim = dict(name="vi safer than hmc offline", family="paper", replicates=[0, 1, 2], per_replicate=[0.0, 0.1],
                 a_rates=[1.0, 1.0], b_rates=[1.0, 0.9, 1.0], experiment="offline", a="vi", b="hmc", paper=None,
                 pairs=29)  # fmt: skip
    path = tmp_path / "findings.json"
    path.write_text(json.dumps(dict(alpha=0.05, margin=0.1, findings=[], claims=[claim])))
    assert main([str(path)]) == 2
    assert json.loads(path.read_text())["claims"] == [claim]  # nothing written over
