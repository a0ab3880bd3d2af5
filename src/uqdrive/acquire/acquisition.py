"""Data acquisition in the learner's own states (DAgger, Ross, Gordon & Bagnell 2011): a controller drives — at each
step the world's expert takes over with probability β instead — and every visited frame is labelled with the
command the expert gives in that state, so the data shows how to come back from where the learner goes.

The expert is the one that produced the training data (`uqdrive.sim.world.World.expert`): uqdrive's autopilot
(unperturbed) in the pybullet world, a Gymnasium world's own. Who drives a step is drawn from the episode's seed on a
stream of its own, so an acquisition episode is a function of its seed, as every rollout is. Below: the records the
`acquire` stage writes (per round, and per controller).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from uqdrive.policy.interface import Command, LockstepPolicy, Policy
from uqdrive.policy.recipes import ExpertSpec, PolicyRecipe
from uqdrive.policy.references import ExpertPolicy
from uqdrive.policy.slots import in_lockstep
from uqdrive.records import record
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.safety.executors import RolloutJob
from uqdrive.safety.rollout import run_rollouts
from uqdrive.sim import AutopilotConfig
from uqdrive.sim.condition import Condition
from uqdrive.sim.world import World
from uqdrive.uq.paired import non_inferior, paired_table, paired_test

MIX_STREAM = 0xDA66E  # who drives each step: a stream of the episode's seed apart from the episode's own draws
RECORDED = ("t", "x", "y", "yaw", "speed", "lateral_deviation")  # info keys kept with each frame (as a collection)


class LabellingPolicy(LockstepPolicy):
    """The learner, or with probability ``beta`` per step the expert, drives; each step's frame, state and the
    expert's label are kept in ``rows`` (one column dict per rollout seed), encoded by ``encode``."""

    def __init__(self, learner: Policy, expert: ExpertPolicy, beta: float, encode: Callable[[np.ndarray], object]):
        self.learner, self.expert, self.beta, self.encode = in_lockstep(learner), expert, float(beta), encode
        self.needs_camera = True
        self.rows: dict[int, dict[str, list]] = {}
        self._seeds: dict[int, int] = {}
        self._coins: dict[int, np.random.Generator] = {}

    def reset(self, seed: int, slot: int = 0, world: World | None = None) -> None:
        self.learner.reset(seed, slot, world)
        self.expert.reset(seed, slot, world)
        self._seeds[slot] = seed
        self._coins[slot] = np.random.default_rng([MIX_STREAM, seed])
        self.rows[seed] = {key: [] for key in (*RECORDED, "step", "steering", "applied_steering", "image")}

    def act_batch(
        self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]
    ) -> list[Command]:
        learned = self.learner.act_batch(slots, frames, infos)  # every step: the learner's draws never depend on β
        commands = []
        for slot, frame, info, own in zip(slots, frames, infos, learned):
            label, speed = self.expert.command(slot, info)
            expert_drives = self._coins[slot].random() < self.beta  # one draw a step, whoever drives
            command = dataclasses.replace(own, steer=label, speed=speed) if expert_drives else own  # η2 etc. kept
            rows = self.rows[self._seeds[slot]]
            for key in RECORDED:
                rows[key].append(info[key])
            rows["step"].append(len(rows["steering"]))
            rows["steering"].append(label)
            rows["applied_steering"].append(command.steer)
            rows["image"].append(self.encode(frame))
            commands.append(command)
        return commands


def acquire_episodes(
    envs: Sequence[World],
    learner: Policy,
    expert: ExpertPolicy,
    beta: float,
    seeds: Sequence[int],
    where: Condition,
    encode: Callable[[np.ndarray], object],
) -> list[dict[str, list]]:
    """The labelled frames of one rollout per seed at ``where`` (`LabellingPolicy`), in seed order: each a column
    dict as a collection's (`uqdrive.sim.episodes`), less the condition's columns."""
    policy = LabellingPolicy(learner, expert, beta, encode)
    run_rollouts(envs, policy, seeds, [where] * len(seeds))
    return [policy.rows[seed] for seed in seeds]


def flagged_cells(cells: Sequence[SafetyCell], target: float) -> list[SafetyCell]:
    """The cells a sweep found unsafe: the upper end of η1's interval below ``target`` (the paper's "problematic
    scenarios in which further data acquisition should occur"), in the order given."""
    return [cell for cell in cells if cell.estimate.high < target]


def expert_job(job: RolloutJob, autopilot: AutopilotConfig) -> RolloutJob:
    """``job`` driven by the world's expert instead of its policy: the same seeds and conditions, paired."""
    recipe: PolicyRecipe = ExpertSpec(autopilot)
    return dataclasses.replace(job, policy=recipe)


@record
class AcquiredAt:
    """Frames one round acquired at one condition."""

    round: int
    condition: str
    episodes: int
    frames: int


@record
class AcquisitionCheck:
    """η̂1 of round ``round``'s controller at check cell ``cell``, and the expert's on the same seeds."""

    method: str
    replicate: int
    round: int
    cell: str
    eta1: float
    low: float
    high: float
    n: int
    expert: float
    expert_low: float
    expert_high: float
    outcomes: str = ""  # each check rollout's 0/1 by seed: every round drives the same seeds, so rounds pair


@record
class BeforeAfter:
    """Round ``round``'s controller against the behaviour-cloned one (round 0) at ``cell``, paired by seed: the gain
    in η̂1, its interval (coverage ≥ 1 − ``level`` for any joint law of the pairs), the exact McNemar p-value and
    the verdict at ``level`` (the family's α split over every comparison: Bonferroni). At the training condition
    also ``non_inferior``: whether the interval's lower end lies above −margin (`uqdrive.uq.paired.non_inferior`;
    acquisition must not buy the flagged conditions with the one the controller was trained for), one more
    comparison of the family."""

    round: int
    cell: str
    gain: float
    low: float
    high: float
    p_value: float
    level: float
    verdict: str  # safer | less safe | undecided
    non_inferior: str = ""  # non-inferior | undecided at the training cell; "" at the others


@record
class RoundSummary:
    """One round: its β, the frames it added (per condition in ``acquired``), the training set it retrained on and
    the retrained controller's validation accuracy (round 0: the behaviour-cloned controller's)."""

    round: int
    beta: float
    frames_added: int
    train_frames: int
    val_accuracy: float
    acquired: list[AcquiredAt]


@record
class RoundRecord:
    """<out_dir>/round<k>/round.json: a finished round, reused by a rerun with the same ``config_hash``."""

    summary: RoundSummary
    checks: list[AcquisitionCheck]
    model: str
    config_hash: str


@record
class Acquisition:
    """metrics/acquire/<experiment>/<method>-<replicate>.json: every round's summary and check rows."""

    method: str
    replicate: int
    experiment: str
    target: float
    flagged: list[str]
    rounds: list[RoundSummary]
    checks: list[AcquisitionCheck]
    before_after: list[BeforeAfter] = dataclasses.field(default_factory=list)
    training: str = ""  # the training condition's cell, checked for non-inferiority every round
    margin: float = 0.1  # within which the training cell must stay


def before_after(
    checks: Sequence[AcquisitionCheck], training: str, margin: float, alpha: float = 0.05
) -> list[BeforeAfter]:
    """Every later round against round 0 at each cell both checked (exact paired tests on the cells' shared seeds),
    and at the ``training`` cell whether it stayed within ``margin`` (non-inferiority), family-wise at ``alpha``
    over all of these (Bonferroni); these trained controllers only, one replicate."""
    first = {c.cell: c for c in checks if c.round == 0 and c.outcomes}
    later = [c for c in checks if c.round > 0 and c.cell in first and len(c.outcomes) == len(first[c.cell].outcomes)]
    level = alpha / max(len(later) + sum(c.cell == training for c in later), 1)
    compared = []
    for c in later:
        table = paired_table([o == "1" for o in c.outcomes], [o == "1" for o in first[c.cell].outcomes])
        test = paired_test(table, level)
        verdict = "undecided" if test.p_value > level else "safer" if test.effect > 0 else "less safe"
        held = "" if c.cell != training else "non-inferior" if non_inferior(table, margin, level) else "undecided"
        compared.append(
            BeforeAfter(c.round, c.cell, test.effect, test.low, test.high, test.p_value, level, verdict, held)
        )
    return compared
