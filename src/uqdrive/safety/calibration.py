"""Choosing the warning thresholds (δ1, δ2, τ) by replaying recorded warnings-off rollouts.

The paper sets δ1 = 0.7, δ2 = 0.6, τ = 0.45 by looking at how uncertainty behaves as the car
approaches the obstacle, and asks of the result two things at once: safety in unknown
conditions, and full autonomy in the known one. Calibration makes that joint claim the
objective: the most replayed unknown-condition safety among the thresholds whose known-condition
autonomy has an exact lower bound ≥ the target. "Always hand over" is safe and useless; the
autonomy constraint is what rules it out, and the never-firing candidate (δ1 = δ2 = 0, τ = 10 nats) is
always on the grid, so a target the known runs can show at all is always met.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from uqdrive.safety.controller import NO_WARNING
from uqdrive.safety.warnings import WarningActions, WarningConfig, classify
from uqdrive.uq import clopper_pearson_interval


@dataclasses.dataclass(frozen=True)
class Traces:
    """Warnings-off rollouts padded to F frames, for replaying warning thresholds over them.

    ``progress``: metres along the route at each frame; ``end_progress``: where the run ended
    (for an unsafe run, where it collided or left the road); ``group``: the run's condition.
    """

    eta2: np.ndarray  # [R, F], padding 1.0
    mutual_information: np.ndarray  # [R, F], padding 0.0
    progress: np.ndarray  # [R, F], padding: the end progress
    frames: np.ndarray  # [R] real frames per run
    end_progress: np.ndarray  # [R]
    safe: np.ndarray  # [R]
    group: np.ndarray  # [R] index into the group names

    @classmethod
    def from_runs(cls, runs: list[tuple[np.ndarray, np.ndarray, np.ndarray, float, bool, int]]) -> Traces:
        """From (eta2, mutual_information, progress, end_progress, safe, group) per run."""
        if not runs:
            raise ValueError("calibration needs at least one recorded rollout")
        width = max(1, max(len(r[0]) for r in runs))
        eta2, mi, progress = np.ones((len(runs), width)), np.zeros((len(runs), width)), np.zeros((len(runs), width))
        for i, (e, m, s, end, _, _) in enumerate(runs):
            eta2[i, : len(e)], mi[i, : len(m)] = e, m
            progress[i] = end
            progress[i, : len(s)] = s
        return cls(
            eta2,
            mi,
            progress,
            np.array([len(r[0]) for r in runs]),
            np.array([r[3] for r in runs], float),
            np.array([r[4] for r in runs], bool),
            np.array([r[5] for r in runs], np.int64),
        )


@dataclasses.dataclass(frozen=True)
class Replay:
    """Replayed outcome per candidate × run: safe, handed over, fraction of frames at full speed."""

    safe: np.ndarray  # [C, R]
    handover: np.ndarray  # [C, R]
    full_speed: np.ndarray  # [C, R]


def replay(
    traces: Traces,
    delta1: np.ndarray,
    delta2: np.ndarray,
    tau: np.ndarray,
    config: WarningConfig,
    control_hz: float,
    cruise: float,
    start_speed: float,
    max_accel: float,
    max_brake: float,
    margin_m: float,
) -> Replay:
    """What candidate thresholds (arrays [C]) would have done on recorded warnings-off runs.

    Approximation (the path is the recorded one; only the speed is replayed):
    each frame is seen where the warnings-off car saw it; the warnings' actions set the speed,
    which follows within the car's accel/brake limits over the distance between frames. A
    hand-over (warning 2 with the default actions) at frame k stops the car within
    v_k²/(2·max_brake); an unsafe run counts as saved if that, plus ``margin_m``, fits before
    the point where it collided or left the road, and a safe run stays safe. Slow-downs change
    the outcome only through a shorter stopping distance; in closed loop they also change the
    path, which is why calibrated thresholds are validated with real rollouts.
    """
    delta1, delta2, tau = (np.asarray(v, float)[:, None] for v in (delta1, delta2, tau))
    n_cand, (n_runs, width) = delta1.shape[0], traces.eta2.shape
    actions = WarningActions(config.actions, round(config.hold_s * control_hz), (n_cand, n_runs))
    speed = np.full((n_cand, n_runs), float(start_speed))
    saved = np.zeros((n_cand, n_runs), dtype=bool)
    stopped_at = np.full((n_cand, n_runs), -1)
    full = np.zeros((n_cand, n_runs))
    for k in range(width):
        live = (k < traces.frames)[None] & (stopped_at < 0)
        levels = classify(traces.eta2[None, :, k], traces.mutual_information[None, :, k], delta1, delta2, tau)
        factor, _, handover = actions.step(np.where(live, levels, NO_WARNING))
        full += live & (factor >= 1.0)
        now = live & handover
        room = traces.end_progress - traces.progress[:, k]
        saved |= now & (room[None] >= speed**2 / (2 * max_brake) + margin_m)
        stopped_at = np.where(now, k, stopped_at)
        step = np.clip((traces.progress[:, min(k + 1, width - 1)] - traces.progress[:, k]), 0, None)[None]
        target = cruise * factor
        up = np.minimum(target, np.sqrt(speed**2 + 2 * max_accel * step))
        down = np.maximum(target, np.sqrt(np.maximum(speed**2 - 2 * max_brake * step, 0)))
        speed = np.where(live, np.where(target >= speed, up, down), speed)
    driven = np.where(stopped_at >= 0, stopped_at + 1, traces.frames[None])
    return Replay(traces.safe[None] | saved, stopped_at >= 0, full / np.maximum(driven, 1))


@dataclasses.dataclass(frozen=True)
class Calibration:
    """Chosen thresholds and every candidate's replayed outcome (the safety–autonomy front).

    ``table`` columns per candidate: delta1, delta2, tau; autonomy (known runs with no hand-over)
    and autonomy_low (its exact lower bound at level 1 − γ); full_speed (known runs' share of
    frames at full speed); eta1_<group> (replayed η̂1 per condition); eta1_unknown (pooled over the
    unknown conditions, equal runs each); feasible (autonomy_low ≥ target); pareto (not beaten in
    both autonomy and eta1_unknown).
    """

    delta1: float
    delta2: float
    tau: float
    feasible: bool
    target: float
    gamma: float
    table: dict[str, np.ndarray]
    chosen: int


NEVER_FIRES = (0.0, 0.0, 10.0)  # η2 < 0 is impossible and MI ≤ ln C < 10 nats: no warning, full autonomy


def candidates(deltas: list[float], taus: list[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every (δ1, δ2, τ) on the grids with δ2 ≤ δ1, plus the candidate that never fires."""
    rows = [(d1, d2, t) for d1 in deltas for d2 in deltas if d2 <= d1 for t in taus]
    rows = [*dict.fromkeys([*rows, NEVER_FIRES])]
    d1, d2, t = (np.array(c, float) for c in zip(*rows))
    return d1, d2, t


def pareto(autonomy: np.ndarray, safety: np.ndarray) -> np.ndarray:
    """Candidates no other beats in both autonomy and safety (ties count as not beaten)."""
    better = (
        (autonomy[None] >= autonomy[:, None])
        & (safety[None] >= safety[:, None])
        & ((autonomy[None] > autonomy[:, None]) | (safety[None] > safety[:, None]))
    )
    return ~better.any(1)


def min_known_runs(target: float, gamma: float) -> int:
    """Fewest known-condition runs whose best case (no hand-over in any) has an exact lower bound ≥ target."""
    n = 1
    while clopper_pearson_interval(n, n, gamma)[0] < target:
        n += 1
    return n


def calibrate(
    traces: Traces,
    groups: list[str],
    config: WarningConfig,
    deltas: list[float],
    taus: list[float],
    target: float,
    gamma: float,
    **replay_args: float,
) -> Calibration:
    """Thresholds that maximise the replayed unknown-condition η̂1 subject to the exact (Clopper–Pearson,
    level 1 − ``gamma``) lower bound of known-condition autonomy being ≥ ``target``.

    ``groups[0]`` is the known condition, the others the unknown ones (``traces.group`` indexes
    ``groups``). Ties go to more autonomy, then more time at full speed, then the candidate
    closest to ``config``'s thresholds. Raises if the known runs are too few for the target to be
    shown at all (see ``min_known_runs``). The replayed outcome is an approximation on the runs
    the thresholds are chosen on: only closed-loop cells on fresh seeds say what they achieve.
    """
    counts = [int(np.sum(traces.group == g)) for g in range(len(groups))]
    if len(groups) < 2 or min(counts) == 0:
        raise ValueError(
            f"calibration needs runs of the known and at least one unknown condition, got {dict(zip(groups, counts))}"
        )
    if counts[0] < min_known_runs(target, gamma):
        raise ValueError(
            f"calibration target={target} needs at least {min_known_runs(target, gamma)} known-condition "
            f"runs at gamma={gamma}; there are {counts[0]}"
        )
    d1, d2, t = candidates(deltas, taus)
    out = replay(traces, d1, d2, t, config, **replay_args)
    known = traces.group == 0
    autonomy = 1 - out.handover[:, known].mean(1)
    table: dict[str, np.ndarray] = {
        "delta1": d1,
        "delta2": d2,
        "tau": t,
        "autonomy": autonomy,
        "autonomy_low": clopper_pearson_interval(np.round(autonomy * counts[0]).astype(int), counts[0], gamma)[0],
        "full_speed": out.full_speed[:, known].mean(1),
    }
    for g, name in enumerate(groups):
        table[f"eta1_{name}"] = out.safe[:, traces.group == g].mean(1)
    table["eta1_unknown"] = out.safe[:, traces.group > 0].mean(1)
    table["feasible"] = table["autonomy_low"] >= target
    table["pareto"] = pareto(autonomy, table["eta1_unknown"])
    distance = np.abs(d1 - config.delta1) + np.abs(d2 - config.delta2) + np.abs(t - config.tau)
    order = np.lexsort((distance, -table["full_speed"], -autonomy, -table["eta1_unknown"], ~table["feasible"]))
    best = int(order[0])
    return Calibration(
        float(d1[best]),
        float(d2[best]),
        float(t[best]),
        bool(table["feasible"][best]),
        float(target),
        float(gamma),
        table,
        best,
    )
