"""Replaying warning rules over recorded warnings-off runs, and choosing thresholds on the paper's joint claim with
Learn-then-Test: the most unknown-condition safety among the thresholds certified to keep known autonomy ≥ the target;
the rule certified is the rule deployed, and a fresh-seed test checks it in closed loop.

p-values are recomputed here from binomial coefficients; the family-wise error is computed exactly by enumerating
every hand-over count, and by 10,000 simulated calibrations for the learned (Pareto Testing) order; the fresh-seed
test's error exactly from binomial probabilities."""

import dataclasses
import itertools
import math

import numpy as np
import pytest
from scipy import stats

from uqdrive.avoid.calibration import (
    NEVER_FIRES,
    calibrate,
    candidates,
    certify,
    firing_order,
    fresh_seed_check,
    min_calibration_runs,
)
from uqdrive.avoid.trace_replay import Replay, Traces, replay
from uqdrive.data.binning import SteeringBins
from uqdrive.policy.draws import DrawSettings
from uqdrive.policy.recipes import ControllerSpec
from uqdrive.policy.warnings import WarningConfig, WarningRule
from uqdrive.records import as_dict

FAST = WarningConfig(theta=0.3)  # the paper's thresholds and actions, 21 draws per frame
RULE = WarningRule(FAST, DrawSettings())  # the paper's fixed draws: η̂2 = k/21 at one look
ARGS = {"control_hz": 15.0, "cruise": 8.0, "start_speed": 8.0, "max_accel": 3.0, "max_brake": 6.0, "margin_m": 0.5}


def run(eta2: np.ndarray, mi: np.ndarray, s: np.ndarray, end: float, safe: bool, group: int) -> tuple:
    """A recorded warnings-off run under the fixed draws: k = round(21 η2) successes at the one look, one MI stage."""
    counts = np.round(np.asarray(eta2) * FAST.samples)[:, None].astype(int)
    stages = np.stack([np.full(len(mi), FAST.samples), mi, np.zeros(len(mi))], -1)[:, None]
    return counts, stages, s, end, safe, group


def rules(delta1, delta2, tau, rule: WarningRule = RULE) -> list[WarningRule]:
    return [rule.with_thresholds(*t) for t in zip(delta1, delta2, tau)]


def traces() -> Traces:
    """Three warnings-off runs, frames 1 m apart: a safe one that wavers (η̂2 19/21 once), one that dips to
    η̂2 = 10/21 twenty metres before it collides, one that collides with no warning sign at all."""
    s = np.arange(30.0)
    calm, wavers = np.ones(30), np.ones(30)
    wavers[12] = 0.9
    dips = np.ones(30)
    dips[9] = 0.5
    runs = [
        run(wavers, np.zeros(30), s, 29.0, True, 0),
        run(dips, np.zeros(30), s, 29.0, False, 1),
        run(calm, np.zeros(30), s, 29.0, False, 1),
    ]
    return Traces.from_runs(runs, RULE.looks)


def test_replay_saves_a_run_only_if_warning_2_fires_a_stopping_distance_before_the_collision():
    t = traces()
    out = replay(t, rules([0.7, 0.95, 0.7], [0.6, 0.95, 0.4], [0.45] * 3), **ARGS)
    assert out.handover.tolist() == [[False, True, False], [True, True, False], [False, False, False]]
    assert out.safe.tolist() == [[True, True, False], [True, True, False], [True, False, False]]
    # the same dip 3 m before the collision is too late at 8 m/s (5.3 m to stop)
    late = dataclasses.replace(t, end_progress=np.array([29.0, 12.0, 29.0]))
    assert not replay(late, rules([0.7], [0.6], [0.45]), **ARGS).safe[0, 1]


def random_traces(rng: np.random.Generator, known: int, unknown: int) -> Traces:
    """Known runs that are safe but waver now and then; unknown runs that dip before colliding, or not at all."""
    s = np.arange(40.0)
    runs = []
    for _ in range(known):
        eta2 = np.ones(40)
        eta2[rng.integers(0, 40, 2)] = rng.uniform(0.55, 1.0, 2)
        runs.append(run(eta2, rng.uniform(0, 0.5, 40), s, 39.0, True, 0))
    for _ in range(unknown):
        eta2 = np.ones(40)
        if rng.random() < 0.7:
            eta2[int(rng.integers(5, 25))] = rng.uniform(0.3, 0.95)
        runs.append(run(eta2, rng.uniform(0, 0.5, 40), s, 39.0, bool(rng.random() < 0.2), 1))
    return Traces.from_runs(runs, RULE.looks)


def binomial_lower_tail(k: int, n: int, p: float) -> float:
    """P(Bin(n, p) ≤ k) from binomial coefficients."""
    return sum(math.comb(n, i) * p**i * (1 - p) ** (n - i) for i in range(k + 1))


DELTAS, TAUS = [0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0], [0.3, 0.45]


@pytest.mark.parametrize("target", [0.6, 0.8, 0.85])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_chosen_thresholds_are_certified_by_an_exact_p_value_and_the_safest_certified(target, seed):
    t = random_traces(np.random.default_rng(seed), known=30, unknown=40)
    calib = calibrate(t, ["known", "unknown"], RULE, DELTAS, TAUS, target=target, gamma=0.05, **ARGS)
    table, chosen = calib.table, calib.chosen
    # the chosen candidate's p-value, recomputed from its replayed hand-overs with binomial coefficients
    handovers = replay(t, [calib.rule], **ARGS).handover[0, t.group == 0]
    assert (calib.certificate.delta1, calib.certificate.delta2, calib.certificate.tau) == (
        table["delta1"][chosen],
        table["delta2"][chosen],
        table["tau"][chosen],
    )
    assert binomial_lower_tail(int(handovers.sum()), handovers.size, 1 - target) <= 0.05
    assert (
        calib.certificate.feasible
        and table["certified"][chosen]
        and calib.certificate.certified == table["certified"].sum()
    )
    # a candidate whose null was not rejected is never chosen: no certified one is safer in the unknown condition
    assert table["eta1_unknown"][chosen] == table["eta1_unknown"][table["certified"]].max()
    assert not table["certified"][table["p_value"] > 0.05].any()
    # fixed-sequence: the certified set is the prefix of the firing order before the first p > gamma
    sequence = firing_order(table["delta1"], table["delta2"], table["tau"])
    assert (table["sequence"][sequence] == np.arange(sequence.size)).all()
    # with the default actions only δ2 decides a hand-over, so the risk grows along the order
    assert (np.diff(table["p_autonomy"][sequence]) >= 0).all()
    assert all(np.unique(table["p_autonomy"][table["delta2"] == v]).size == 1 for v in np.unique(table["delta2"]))
    failed = np.flatnonzero(table["p_value"][sequence] > 0.05)
    assert failed.size and table["certified"][sequence].tolist() == [i < failed[0] for i in range(sequence.size)]
    always = np.flatnonzero(table["delta2"] == 1.0)  # hand over at the first frame with any disagreement
    assert not table["certified"][always].any() and table["autonomy"][always].max() < 0.5
    assert calib.certificate.calibration_runs == {"known": 30, "unknown": 40} and calib.certificate.learn_runs == {
        "known": 0,
        "unknown": 0,
    }
    assert f"each of the {calib.certificate.certified} certified candidates" in calib.certificate.guarantee


def test_nothing_certifiable_falls_back_to_the_never_firing_candidate_and_says_so():
    """10 known calibration runs without a hand-over give p = 0.8^10 = 0.107 for "hand-over rate > 0.2"."""
    t = random_traces(np.random.default_rng(0), known=20, unknown=10)
    calib = calibrate(
        t, ["known", "unknown"], RULE, DELTAS, TAUS, target=0.8, gamma=0.05, calibration_fraction=0.5, **ARGS
    )
    never = list(zip(calib.table["delta1"], calib.table["delta2"], calib.table["tau"])).index(NEVER_FIRES)
    assert calib.certificate.calibration_runs == {"known": 10, "unknown": 5} and calib.certificate.learn_runs == {
        "known": 10,
        "unknown": 5,
    }
    assert calib.table["p_value"][never] == pytest.approx(0.8**10, rel=1e-12)
    assert not calib.certificate.feasible and calib.certificate.certified == 0 and calib.chosen == never
    assert (calib.certificate.delta1, calib.certificate.delta2, calib.certificate.tau) == NEVER_FIRES
    assert (
        calib.certificate.max_certifiable_target == pytest.approx(0.05 ** (1 / 10))
        and "Nothing certified at gamma=0.05" in calib.certificate.guarantee
    )
    assert "can certify known-condition autonomy ≥ 0.741 at most" in calib.certificate.guarantee


def test_fewest_runs_that_can_certify_a_target():
    for target, gamma in ((0.8, 0.05), (0.95, 0.05), (0.3, 0.05), (0.9, 0.1)):
        fewest = next(n for n in range(1, 1000) if binomial_lower_tail(0, n, 1 - target) <= gamma)
        assert min_calibration_runs(target, gamma) == fewest
        assert min_calibration_runs(target, gamma, 0.5) == 2 * fewest  # every other index calibrates
    assert min_calibration_runs(0.8, 0.05) == 14 and min_calibration_runs(0.95, 0.05) == 59


def test_the_never_firing_candidate_is_on_every_grid_first_in_the_firing_order():
    d1, d2, t = candidates([0.7, 0.9], [0.45, 1.0])
    first = firing_order(d1, d2, t)[0]
    assert NEVER_FIRES in list(zip(d1, d2, t)) and (d1[first], d2[first], t[first]) == NEVER_FIRES
    with pytest.raises(ValueError, match="'learned' needs calibration_fraction < 1"):
        calibrate(traces(), ["known", "unknown"], RULE, [0.7], [0.45], target=0.5, gamma=0.05, order="learned", **ARGS)


def test_the_learned_order_reads_only_the_learn_split():
    """Every other run index learns the order; making the calibration runs hand over changes their p-values and
    nothing about the order."""
    t = random_traces(np.random.default_rng(4), known=30, unknown=30)
    args = {"target": 0.6, "gamma": 0.05, "calibration_fraction": 0.5, "order": "learned"}
    calib = calibrate(t, ["known", "unknown"], RULE, DELTAS, TAUS, **args, **ARGS)
    calibration_known = (t.group == 0) & (np.arange(t.group.size) % 2 == 1)  # known runs come first: index = row
    counts = t.eta2_counts.copy()
    counts[calibration_known, 3] = 12  # η̂2 = 12/21, below every δ2 but 0.5: those candidates now hand over here
    shaken = calibrate(
        dataclasses.replace(t, eta2_counts=counts), ["known", "unknown"], RULE, DELTAS, TAUS, **args, **ARGS
    )
    assert (shaken.table["sequence"] == calib.table["sequence"]).all()
    assert (shaken.table["p_value"] >= calib.table["p_value"]).all()
    assert (shaken.table["p_value"] > calib.table["p_value"]).any()
    assert (
        calib.certificate.calibration_runs == calib.certificate.learn_runs == {"known": 15, "unknown": 15}
        and calib.certificate.order == "learned"
    )
    in_order = np.argsort(np.where(calib.table["sequence"] < 0, np.inf, calib.table["sequence"]))
    tested = in_order[: int((calib.table["sequence"] >= 0).sum())]
    certified = calib.table["certified"][tested]
    assert certified.tolist() == sorted(certified.tolist(), reverse=True)  # a prefix of the learned order


def test_a_silent_failure_is_never_saved_by_any_threshold():
    calib = calibrate(
        traces(), ["known", "unknown"], RULE, [0.5, 0.6, 0.7, 0.9, 0.95, 1.0], [0.45], target=0.02, gamma=0.05, **ARGS
    )
    # the dipping collision can be saved, the silent one never: unknown η̂1 tops out at 1/2
    assert calib.certificate.feasible and calib.table["eta1_unknown"].max() == 0.5
    assert calib.table["eta1_unknown"][calib.chosen] == 0.5


def synthetic(handover: np.ndarray, unsafe: np.ndarray | None = None) -> tuple[Replay, np.ndarray]:
    """Replayed outcomes of candidates × runs: known runs first (``handover``), then unknown runs (``unsafe``)."""
    unsafe = np.zeros((handover.shape[0], 0), bool) if unsafe is None else unsafe
    group = np.r_[np.zeros(handover.shape[1], np.int64), np.ones(unsafe.shape[1], np.int64)]
    safe = np.c_[np.ones_like(handover), ~unsafe]
    out = Replay(safe, np.c_[handover, np.zeros_like(unsafe)], np.ones(safe.shape, float))
    return out, group


def test_family_wise_error_of_the_firing_order_is_at_most_gamma_exactly():
    """Candidates in firing order: never-firing; hand-over rate 0.2001 (null true); 0.1 (false); 0.2001 (true).
    Every triple of hand-over counts is enumerated with its exact probability. Testing all four at γ without
    stopping would err with probability 1 − (1 − 0.8^14)² ≈ 0.086; the fixed sequence errs only if candidate 1's
    null is rejected (0.7999^14 ≈ 0.0439)."""
    n, target, gamma, rates = 14, 0.8, 0.05, (0.0, 0.2001, 0.1, 0.2001)
    table = {"delta1": np.zeros(4), "delta2": np.arange(4.0), "tau": np.zeros(4)}
    pmf = [np.array([math.comb(n, k) * q**k * (1 - q) ** (n - k) for k in range(n + 1)]) for q in rates[1:]]
    error = 0.0
    for counts in itertools.product(range(n + 1), repeat=3):
        handover = np.arange(n)[None] < np.array([0, *counts])[:, None]
        out, group = synthetic(handover)
        certified = certify(out, group, np.ones(n, bool), table, target, gamma, None, "firing")["certified"]
        if certified[[1, 3]].any():
            error += math.prod(p[k] for p, k in zip(pmf, counts))
    assert 0.04 < error <= gamma


def test_family_wise_error_of_pareto_testing_with_two_constraints_by_simulation():
    """Two constraints (autonomy ≥ 0.8, missed collisions ≤ 0.3), the order learned on every other run and the
    tests on the rest. Candidate 0 misses too many collisions, 1-2 meet both, 3-7 hand over just too often
    (0.201) while missing few collisions, so the learn split often ranks one of them first. 10,000 calibrations
    (outcomes independent across candidates): the error rate's exact 95% upper bound stays below γ. Learning
    the order on the calibration runs themselves errs about 19% of the time here."""
    rng = np.random.default_rng(7)
    target, limit, gamma, n, reps = 0.8, 0.3, 0.05, 100, 10_000
    handover_rate = np.array([0.0, 0.08, 0.1, 0.201, 0.201, 0.201, 0.201, 0.201])
    missed_rate = np.array([0.5, 0.22, 0.18, 0.1, 0.1, 0.1, 0.1, 0.1])
    bad = (handover_rate > 1 - target) | (missed_rate > limit)
    table = {"delta1": np.zeros(8), "delta2": np.arange(8.0), "tau": np.zeros(8)}
    calibrating = np.r_[np.arange(n) % 2 == 1, np.arange(n) % 2 == 1]
    handover = rng.random((reps, 8, n)) < handover_rate[:, None]
    unsafe = rng.random((reps, 8, n)) < missed_rate[:, None]
    errors = 0
    for r in range(reps):
        out, group = synthetic(handover[r], unsafe[r])
        certified = certify(out, group, calibrating, table, target, gamma, limit, "learned")["certified"]
        errors += bool(certified[bad].any())
    assert stats.beta.ppf(0.975, errors + 1, reps - errors) < gamma


def sequential_traces(rng: np.random.Generator, looks: tuple[int, ...], known: int = 30, unknown: int = 30) -> Traces:
    """Runs recorded with sequential draws: each frame's η2 stream drawn at a rate (mostly 0.97; now and then lower,
    an unknown run's dip before it collides), its successes counted at every look; one MI stage at the cap."""
    s, runs = np.arange(40.0), []
    for group, count in ((0, known), (1, unknown)):
        for _ in range(count):
            rate = np.full(40, 0.97)
            rate[rng.integers(5, 25, 2)] = rng.uniform(0.3, 0.9, 2) if group or rng.random() < 0.3 else 0.97
            streams = rng.random((40, looks[-1])) < rate[:, None]
            counts = np.cumsum(streams, 1)[:, np.array(looks) - 1]
            stages = np.stack([np.full(40, looks[-1]), rng.uniform(0, 0.5, 40), np.zeros(40)], -1)[:, None]
            runs.append((counts, stages, s, 39.0, bool(group == 0 or rng.random() < 0.3), group))
    return Traces.from_runs(runs, looks)


def test_the_certificate_names_the_deployed_rule_and_swapping_its_tier_settings_changes_it():
    """Two deployed rules that differ only in their tier test's θ and γ, replayed on the same recorded streams
    (same looks): each calibration certifies and returns its own rule, and says so."""
    config = WarningConfig(theta=0.1)  # cap 185
    loose, tight = (
        WarningRule(config, DrawSettings("sequential", theta=t, gamma=g)) for t, g in ((0.2, 0.1), (0.1, 0.05))
    )
    t = sequential_traces(np.random.default_rng(3), loose.looks)
    out = {}
    for rule in (loose, tight):
        out[rule] = calibrate(t, ["known", "unknown"], rule, DELTAS, TAUS, target=0.6, gamma=0.05, **ARGS)
        assert out[rule].rule.draws is rule.draws and out[rule].certificate.feasible
        assert f"Chosen and deployed rule: {out[rule].rule.describe()}." in out[rule].certificate.guarantee
    assert "sequential tier rule theta=0.2, gamma=0.1" in out[loose].certificate.guarantee
    assert "sequential tier rule theta=0.1, gamma=0.05" in out[tight].certificate.guarantee
    assert out[loose].certificate.guarantee != out[tight].certificate.guarantee
    assert "exact up to a run's first warning action" in out[tight].certificate.guarantee
    assert not np.array_equal(out[loose].table["p_value"], out[tight].table["p_value"])  # the tiers differ


def test_the_calibrated_cell_deploys_the_very_rule_it_certified(random_models):
    rule = WarningRule(WarningConfig(theta=0.1), DrawSettings("sequential", theta=0.1))
    t = sequential_traces(np.random.default_rng(4), rule.looks)
    calib = calibrate(t, ["known", "unknown"], rule, DELTAS, TAUS, target=0.6, gamma=0.05, **ARGS)
    spec = ControllerSpec(8.0, str(random_models["vi"]), "vi", SteeringBins(), calib.rule.cap, 0.1, draws=rule.draws)
    deployed = dataclasses.replace(spec, warnings=calib.rule).build(15.0)
    assert deployed.rule is calib.rule and deployed.tier is calib.rule.tier
    assert (calib.certificate.delta1, calib.certificate.delta2, calib.certificate.tau) == (
        deployed.rule.config.delta1,
        deployed.rule.config.delta2,
        deployed.rule.config.tau,
    )


def test_traces_without_every_look_recorded_are_refused():
    stages = np.zeros((3, 1, 3))
    with pytest.raises(ValueError, match=r"run 0 records \(3, 2\) η2 counts and \(3, 1, 3\) MI stages for 3 frames"):
        Traces.from_runs([(np.ones((3, 2), int), stages, np.arange(3.0), 3.0, True, 0)], (8, 16, 21))


def binomial_upper_tail(k: int, n: int, p: float) -> float:
    """P(Bin(n, p) ≥ k) from binomial coefficients."""
    return sum(math.comb(n, i) * p**i * (1 - p) ** (n - i) for i in range(k, n + 1))


@pytest.mark.parametrize(("runs", "target"), [(14, 0.8), (36, 0.8), (100, 0.95), (100, 0.8)])
def test_the_fresh_seed_check_declares_a_target_met_at_most_at_its_level_when_autonomy_is_below_it(runs, target):
    """The deployed rule's true known-condition autonomy a (a synthetic problem: each fresh run is autonomous with
    probability a, independently); for every a below the target the probability that the check says "met" is
    computed exactly from binomial probabilities: ≤ the level, and it approaches the level near the target when the
    test can reach it. With no hand-over at all the target is met when the runs can show it."""
    level = 0.05
    checks = [fresh_seed_check(np.arange(runs) < runs - k, target, level) for k in range(runs + 1)]  # k autonomous
    for k, check in enumerate(checks):
        assert (check.runs, check.autonomous) == (runs, k)
        assert check.p_value == pytest.approx(binomial_upper_tail(k, runs, target), rel=1e-9, abs=1e-15)
    met = np.array([c.target_met for c in checks])
    worst = 0.0
    for a in np.linspace(0, target, 401)[:-1]:  # H0: a < target
        pmf = np.array([math.comb(runs, k) * a**k * (1 - a) ** (runs - k) for k in range(runs + 1)])
        worst = max(worst, float(pmf[met].sum()))
    assert worst <= level
    assert checks[-1].target_met == (target**runs <= level)
    if runs >= 36:
        assert worst > level / 5  # the test is not vacuous


def test_the_fresh_seed_check_is_a_record_with_its_p_value():
    check = fresh_seed_check([False] * 14, 0.8, 0.05)
    assert as_dict(check) == {
        "runs": 14,
        "autonomous": 14,
        "target": 0.8,
        "level": 0.05,
        "p_value": pytest.approx(0.8**14),
        "target_met": True,
    }
    assert not fresh_seed_check([False] * 13 + [True], 0.8, 0.05).target_met  # 13/14 = 0.93 ≥ 0.8, but p = 0.198
    with pytest.raises(ValueError, match="one hand-over flag per run"):
        fresh_seed_check([], 0.8, 0.05)


def test_the_replay_takes_the_mi_a_warning_controller_stops_at_not_the_recorded_cap():
    """A recorded frame whose first 24 draws agree (MI 0, which decides τ = 0.45 since h(3/24) = 0.38 < 0.45) but
    whose draws to the cap disagree (MI 0.9): a controller at τ = 0.45 stops at 24 draws and raises no warning 0; one
    at τ = 0.1 (undecided at 24) draws on and slows down. The replay must read the stages as they do."""
    rule = WarningRule(WarningConfig(theta=0.1, delta1=0.0, delta2=0.0), DrawSettings("sequential", theta=0.1))
    stages = np.full((30, 3, 3), np.nan)
    stages[:, 0] = (24, 0.0, 0.0)
    stages[12] = [(24, 0.0, 0.0), (48, 0.9, 0.01), (185, 0.9, 0.01)]
    counts = np.broadcast_to(np.array(rule.looks), (30, len(rule.looks)))
    t = Traces.from_runs([(counts, stages, np.arange(30.0), 29.0, True, 0)], rule.looks)
    out = replay(t, [rule.with_thresholds(0, 0, 0.45), rule.with_thresholds(0, 0, 0.1)], **ARGS)
    assert out.full_speed[0, 0] == 1.0 and out.full_speed[1, 0] < 1.0
