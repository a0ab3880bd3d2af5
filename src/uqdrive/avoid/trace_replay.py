"""Replaying warning rules over recorded warnings-off rollouts: what each candidate rule would have done.

A warnings-off rollout records, frame by frame, the successes at every look of the frame's η2 stream and the MI
at every stage of its π(o) draws, to the cap: the streams a warning controller reads on that seed
(`uqdrive.policy.draws`). A candidate `WarningRule` reads them as its controller would (`TierRule.tiers`,
`refined_mutual_information`), so its warning levels, and whether and where it first acts, are exactly the
controller's until its first action changes a command.
Past a slow-down the replay keeps the recorded path and replays the speed only: in closed loop the path departs
from the recorded one, which is why calibrated rules are checked in closed loop on fresh seeds. In a Gymnasium
world the car is the env's: speeds and stopping distances are replayed with uqdrive's car's limits as a model of
it, and a run counts as saved when it stops short of where it ended along its own path, which with moving traffic
does not mean the collision is avoided; only the replayed safety (the choice among certified candidates) reads
this, never the certified autonomy.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from uqdrive.policy.draws import refined_mutual_information
from uqdrive.policy.interface import NO_WARNING
from uqdrive.policy.warnings import WarningActions, WarningRule, levels_of


@dataclasses.dataclass(frozen=True)
class Traces:
    """Warnings-off rollouts padded to F frames, for replaying warning rules over them.

    ``eta2_counts``: successes at each of ``looks`` of every frame's η2 stream; ``mi_stages``: (draws, MI, SE) at
    each stage of its π(o) draws; ``progress``: metres along the route at each frame; ``end_progress``: where the
    run ended (for an unsafe run, where it collided or left the road); ``group``: the run's condition.
    """

    eta2_counts: np.ndarray  # [R, F, looks], padding: every draw within ε
    looks: tuple[int, ...]
    mi_stages: np.ndarray  # [R, F, S, 3], padding: one stage of MI 0
    progress: np.ndarray  # [R, F], padding: the end progress
    frames: np.ndarray  # [R] real frames per run
    end_progress: np.ndarray  # [R]
    safe: np.ndarray  # [R]
    group: np.ndarray  # [R] index into the group names

    @classmethod
    def from_runs(
        cls, runs: list[tuple[np.ndarray, np.ndarray, np.ndarray, float, bool, int]], looks: Sequence[int]
    ) -> Traces:
        """From (eta2_counts [frames, looks], mi_stages [frames, S, 3], progress, end_progress, safe, group) per
        run (`RolloutResult`'s fields), recorded at ``looks`` (`DrawSettings.looks` of the rules to replay)."""
        if not runs:
            raise ValueError("calibration needs at least one recorded rollout")
        looks = tuple(int(n) for n in looks)
        width = max(1, max(len(r[2]) for r in runs))
        depth = max(1, max(np.shape(r[1])[1] if len(r[2]) else 1 for r in runs))
        counts = np.broadcast_to(np.array(looks), (len(runs), width, len(looks))).copy()
        stages = np.full((len(runs), width, depth, 3), np.nan)
        progress = np.zeros((len(runs), width))
        for i, (c, m, s, end, _, _) in enumerate(runs):
            frames, c, m = len(s), np.asarray(c), np.asarray(m, float)
            if frames and (c.shape != (frames, len(looks)) or (c < 0).any() or m.shape[::2] != (frames, 3)):
                raise ValueError(
                    f"run {i} records {c.shape} η2 counts and {m.shape} MI stages for {frames} frames, not every "
                    f"look of {looks}: record the warnings-off cells with draws.unacted=record and the rules' draws"
                )
            if frames:
                counts[i, :frames], stages[i, :frames, : m.shape[1]] = c, m
            stages[i, frames:, 0] = (looks[-1], 0.0, 0.0)  # padding: MI 0, decided for every τ
            progress[i] = end
            progress[i, :frames] = s
        return cls(
            counts,
            looks,
            stages,
            progress,
            np.array([len(r[2]) for r in runs]),
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


def replayed_inputs(traces: Traces, rules: Sequence[WarningRule]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each rule's η2 tiers and MI on the traces, computed once per distinct tier rule and τ: tiers [P, R, F] and
    MI [T, R, F], with each rule's index into both [C, 2]."""
    if any(rule.looks != traces.looks for rule in rules):
        raise ValueError(
            f"the traces record η2 at looks {traces.looks}; a rule reads {rules[0].looks}: replay rules with the "
            "draw settings and cap the warnings-off cells drove with"
        )
    pairs = [(rule.config.delta1, rule.config.delta2) for rule in rules]
    taus = [rule.config.tau for rule in rules]
    distinct_pairs, distinct_taus = list(dict.fromkeys(pairs)), list(dict.fromkeys(taus))
    tier_rules = {pair: rule.tier for pair, rule in zip(pairs, rules)}
    tiers = np.stack([tier_rules[pair].tiers(traces.eta2_counts) for pair in distinct_pairs])
    mi = np.stack([refined_mutual_information(traces.mi_stages, tau) for tau in distinct_taus])
    index = np.array([(distinct_pairs.index(p), distinct_taus.index(t)) for p, t in zip(pairs, taus)])
    return tiers, mi, index


def replay(
    traces: Traces,
    rules: Sequence[WarningRule],
    control_hz: float,
    cruise: float,
    start_speed: float,
    max_accel: float,
    max_brake: float,
    margin_m: float,
) -> Replay:
    """What each of ``rules`` (sharing actions and hold) would have done on recorded warnings-off runs.

    Each frame's level is the rule's on the frame's recorded draws, exact until the rule's first action (module
    docstring); the actions set the speed, which follows within the car's accel/brake limits over the distance
    between recorded frames. A hand-over (warning 2 with the default actions) at frame k stops the car within
    v_k²/(2·max_brake); an unsafe run counts as saved if that, plus ``margin_m``, fits before the point where it
    collided or left the road, and a safe run stays safe. Slow-downs change the outcome only through a shorter
    stopping distance here; in closed loop they also change the path.
    """
    config = rules[0].config
    if any((r.config.actions, r.config.hold_s) != (config.actions, config.hold_s) for r in rules):
        raise ValueError("replayed rules must share their actions and hold_s (they differ only in thresholds)")
    tiers, mi, index = replayed_inputs(traces, rules)
    tau = np.array([rule.config.tau for rule in rules])[:, None]
    n_rules, (n_runs, width) = len(rules), traces.progress.shape
    actions = WarningActions(config.actions, round(config.hold_s * control_hz), (n_rules, n_runs))
    speed = np.full((n_rules, n_runs), float(start_speed))
    saved = np.zeros((n_rules, n_runs), dtype=bool)
    stopped_at = np.full((n_rules, n_runs), -1)
    full = np.zeros((n_rules, n_runs))
    for k in range(width):
        live = (k < traces.frames)[None] & (stopped_at < 0)
        levels = levels_of(tiers[:, :, k][index[:, 0]], mi[:, :, k][index[:, 1]], tau)
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
