"""One closed-loop episode: seed → start jitter, weather effects, sensor noise and posterior draws → verdict.

Everything random in rollout i comes from its seed (``base_seed + i``), so a rollout gives
the same result in any process, with any backend, in any order. A policy that hands control
to the operator (``Command.handover``) brakes to a stop; the rollout then ends with termination
``handover`` and is judged by the safe set like any other path.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from uqdrive.policy.interface import Command, Policy
from uqdrive.policy.slots import in_lockstep
from uqdrive.safety.info_safe_set import AnySafeSet, SafeSetOf
from uqdrive.safety.safe_sets import HANDOVER, PathVerdict
from uqdrive.sim.condition import Condition
from uqdrive.sim.world import World


def _empty() -> np.ndarray:
    return np.zeros(0)


@dataclass(frozen=True)
class RolloutResult:
    """Outcome of one episode: how it ended (``termination``) and the safe set's ``verdict`` on its path; ``x``,
    ``y``, ``yaw`` are the body-centre poses at every control step
    (and the last pose). Per-decision traces (one value per step): ``eta2``, ``mutual_information``,
    ``warning`` (level, -1 for none), ``command_speed``, ``draws`` (posterior draws the step took),
    ``mutual_information_se`` (how precise the MI is at those draws: its jackknife standard error) and
    ``eta2_counts`` [steps, looks] (successes at each look of the step's η2 stream; -1 past the looks read) and
    ``mi_stages`` [steps, stages, 3] (draws, MI, SE at each stage of its π(o) draws; NaN past those read): what a
    warning rule reads (`uqdrive.policy.warnings.WarningRule.levels`)."""

    seed: int
    termination: str
    verdict: PathVerdict
    mean_abs_lateral_deviation: float
    mean_eta2: float
    mean_mutual_information: float
    steps: int
    x: np.ndarray
    y: np.ndarray
    eta2: np.ndarray = field(default_factory=_empty)
    yaw: np.ndarray = field(default_factory=_empty)  # where a failure record places a lane exit (`first_exit`)
    mutual_information: np.ndarray = field(default_factory=_empty)
    warning: np.ndarray = field(default_factory=_empty)
    command_speed: np.ndarray = field(default_factory=_empty)
    draws: np.ndarray = field(default_factory=_empty)
    mutual_information_se: np.ndarray = field(default_factory=_empty)
    eta2_counts: np.ndarray = field(default_factory=_empty)
    mi_stages: np.ndarray = field(default_factory=_empty)
    min_time_to_boundary: float = float("nan")  # s: the safe set's `time_to_boundary` of the path (NaN: not measured)

    def summary(self) -> dict:
        """The scalar fields, the verdict's among them (one row of the per-rollout table: seed, outcome and
        termination first, then why)."""
        row = {"seed": self.seed, "safe": self.verdict.safe, "termination": self.termination, **asdict(self.verdict)}
        rest = {k: v for k, v in self.__dict__.items() if k not in row and not isinstance(v, np.ndarray | PathVerdict)}
        return row | rest


def run_rollout(
    env: World,
    policy: Policy,
    seed: int,
    condition: Condition,
    half_width: float | None = None,
    safe_set: AnySafeSet | None = None,
) -> RolloutResult:
    """Drive one episode until the env ends it (collision, off road, route complete or horizon T)
    or the policy has handed over and the car has stopped.

    The episode runs to its end even after the car leaves the corridor, so collision and
    off-road rates and the visited positions describe the whole path.
    """
    return run_rollouts([env], policy, [seed], [condition], half_width, safe_set)[0]


@dataclass
class _Episode:
    """A rollout under way in one lockstep slot."""

    index: int
    seed: int
    env: World
    obs: np.ndarray | None
    info: dict
    termination: str
    commands: list[Command] = field(default_factory=list)


def run_rollouts(
    envs: Sequence[World],
    policy: Policy,
    seeds: Sequence[int],
    conditions: Sequence[Condition],
    half_width: float | None = None,
    safe_set: AnySafeSet | None = None,
    on_done: Callable[[], None] | None = None,
) -> list[RolloutResult]:
    """The rollouts of ``seeds`` (in that order), each at its own of ``conditions``, ``len(envs)`` at a time in
    lockstep: each control step asks the policy for the commands of every running slot at once, and a slot whose
    rollout ends starts the next seed. A ``safe_set`` given must hold for every condition's location (else each
    rollout is judged on its own). ``on_done()`` as each rollout ends (a progress bar's tick).

    Each rollout is what `run_rollout` gives it alone: its env is reset with its own seed and the policy's slot
    draws from it only (`Controller`: the frames' features and draws do not depend on the other slots). Any
    `Policy` drives: through its lockstep fast path, or an instance per slot (`in_lockstep`).
    """
    policy = in_lockstep(policy)
    results: list[RolloutResult | None] = [None] * len(seeds)
    queue = iter(enumerate(seeds))
    running: dict[int, _Episode] = {}
    done = on_done or (lambda: None)

    def start(slot: int) -> None:
        env = envs[slot]
        for index, seed in queue:
            where = conditions[index]
            obs = env.reset(seed, where, render=policy.needs_camera)
            policy.reset(seed, slot=slot, world=env)
            episode = _Episode(index, seed, env, obs, env.last_info, env.last_info["termination"])
            if not env.done:
                running[slot] = episode
                return
            results[index] = _result(episode, safe_set, half_width)
            done()

    for slot in range(len(envs)):
        start(slot)
    while running:
        slots = list(running)
        episodes = [running[slot] for slot in slots]
        commands = policy.act_batch(slots, [e.obs for e in episodes], [e.info for e in episodes])
        for slot, episode, command in zip(slots, episodes, commands):
            episode.commands.append(command)
            episode.obs, episode.info = episode.env.apply(command)
            episode.termination = episode.info["termination"]
            stopped = (
                not episode.termination and command.handover and episode.info["speed"] <= episode.env.stopped_speed
            )
            if stopped:
                episode.termination = HANDOVER
            if stopped or episode.env.done:
                results[episode.index] = _result(episode, safe_set, half_width)
                done()
                del running[slot]
                start(slot)
    return results


def _result(episode: _Episode, safe_set: AnySafeSet | None, half_width: float | None) -> RolloutResult:
    """Judge a finished episode (before its env starts another): by ``safe_set``, else by the safe set of the
    location its env is at."""
    env, commands = episode.env, episode.commands
    safe_set = safe_set or env.visit(SafeSetOf(env.car_size, half_width))
    eta2 = [c.eta2 for c in commands]
    mi = [c.mutual_information for c in commands]
    log = env.trajectory
    verdict = safe_set.judge(env.lane, log["x"], log["y"], log["yaw"], episode.termination)
    _, lateral = env.lane.local_coordinates(np.stack([log["x"], log["y"]], axis=1))
    return RolloutResult(
        seed=episode.seed,
        termination=episode.termination,
        verdict=verdict,
        mean_abs_lateral_deviation=float(np.mean(np.abs(lateral))),
        mean_eta2=float(np.mean(eta2)) if eta2 else float("nan"),
        mean_mutual_information=float(np.mean(mi)) if mi else float("nan"),
        steps=len(commands),
        x=log["x"],
        y=log["y"],
        yaw=log["yaw"],
        eta2=np.array(eta2, dtype=float),
        mutual_information=np.array(mi, dtype=float),
        warning=np.array([c.warning for c in commands], dtype=np.int8),
        command_speed=np.array([c.speed for c in commands], dtype=float),
        draws=np.array([c.draw_count for c in commands], dtype=np.int32),
        mutual_information_se=np.array([c.mutual_information_se for c in commands], dtype=float),
        eta2_counts=_padded([c.eta2_counts for c in commands], -1, np.int32),
        mi_stages=_padded([c.mi_stages for c in commands], np.nan, float),
        min_time_to_boundary=safe_set.time_to_boundary(env.lane, log["x"], log["y"], log["yaw"], log["speed"]),
    )


def _padded(rows: list[tuple], fill: float, dtype: type) -> np.ndarray:
    """[steps, longest, ...] of each step's tuple, ``fill`` past its end."""
    width = max((len(row) for row in rows), default=0)
    inner = next((np.shape(row)[1:] for row in rows if len(row)), ())
    out = np.full((len(rows), width, *inner), fill, dtype=dtype)
    for i, row in enumerate(rows):
        out[i, : len(row)] = row
    return out
