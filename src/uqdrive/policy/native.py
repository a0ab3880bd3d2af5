"""An agent over the env's own spaces: it observes what a Gymnasium env returns (any space: Box vectors and images,
Dict, Tuple, Discrete) and acts in the env's action space (Discrete, MultiDiscrete, Box), where the world is driven
as it is (``gym_world.hooks: native``; ``uqdrive certify --env ID``).

What an agent may be (`agent_of`): an object with ``act(obs, info)`` (and optionally ``reset(seed)``), one with
stable-baselines3's ``predict(obs, deterministic=...)`` (an SB3 model or its policy network, `PredictAgent`), a
plain function ``f(obs)`` or ``f(obs, info)`` (`FunctionAgent`), or a network over the observation (`TensorAgent`:
TorchScript or ONNX). Its act may return the action itself, or an `Action` with ``env_action`` and ``draws`` —
class probabilities [n, C] over a Discrete(C) space's actions, or n action draws [n, *shape] of a Box — from which
η2 (the share of draws that decide the agent's action; within ``eps`` in max-norm for a Box), mutual information
and entropy are read as for uqdrive's own controllers.

`NativeSlots` runs it in lockstep slots, one instance per slot, as `uqdrive.policy.slots.PolicySlots` runs a
frame policy: at each episode's reset it checks the spaces the agent declares (``observation_space``,
``action_space``: an SB3 agent's saved ones) against the env's, and every action against the env's action space (the
world refuses one outside it, with the seed and step).
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from uqdrive.policy.interface import Action, Command, LockstepPolicy
from uqdrive.policy.slots import PolicyFailure, guarded
from uqdrive.policy.warnings import WarningConfig, classify
from uqdrive.uq import draw_measures

NOT_NATIVE = "an agent over an env's own spaces needs a world driven as it is (--env ID, or gym_world hooks: native)"


class FunctionAgent:
    """A plain function as an agent: ``fn(obs)`` or ``fn(obs, info)`` (by its parameters), with keyword settings."""

    def __init__(self, fn: Callable[..., Any], settings: dict[str, Any] | None = None):
        self.fn, self.settings = fn, dict(settings or {})
        try:
            params = [p for p in inspect.signature(fn).parameters.values() if p.default is inspect.Parameter.empty]
        except (TypeError, ValueError):  # a builtin without a signature: one argument
            params = []
        self.with_info = len([p for p in params if p.name not in self.settings]) >= 2

    def reset(self, seed: int) -> None:
        """A function keeps no episode state."""

    def act(self, obs: Any, info: dict) -> Any:
        return self.fn(obs, info, **self.settings) if self.with_info else self.fn(obs, **self.settings)


class PredictAgent:
    """An object with stable-baselines3's ``predict(obs, deterministic=True) -> (action, state)``; its declared
    spaces (``observation_space``, ``action_space``) are checked against the env's."""

    def __init__(self, model: Any):
        self.model = model
        self.observation_space = getattr(model, "observation_space", None)
        self.action_space = getattr(model, "action_space", None)

    def reset(self, seed: int) -> None:
        reset = getattr(self.model, "reset", None)
        if callable(reset):
            reset(seed)

    def act(self, obs: Any, info: dict) -> Any:
        action, _ = self.model.predict(obs, deterministic=True)
        return action


class TensorAgent:
    """A network over the env's observation (a Box: [1, *shape] float32): its output [1, K] is the action — the
    arg-max of K = n logits for Discrete(n), of each of MultiDiscrete's segments of logits, or the K values of a
    Box of that many (not clipped: an action outside the space is refused). ``run``: the network on a batch."""

    def __init__(self, name: str, run: Callable[[np.ndarray], np.ndarray]):
        self.name, self.run, self.space = name, run, None

    def bind(self, observation_space: Any, action_space: Any) -> None:
        """The env's spaces, at each episode's reset."""
        if getattr(observation_space, "shape", None) is None:
            raise PolicyFailure(f"{self.name}: a network takes a Box observation, got {observation_space}")
        self.space = action_space

    def reset(self, seed: int) -> None:
        """Deterministic: nothing to seed."""

    def act(self, obs: Any, info: dict) -> Any:
        out = np.asarray(self.run(np.asarray(obs, dtype=np.float32)[None])).reshape(-1)
        space = self.space
        if hasattr(space, "nvec"):
            cuts = np.cumsum(np.asarray(space.nvec).reshape(-1))
            if out.size != cuts[-1]:
                raise PolicyFailure(f"{self.name}: expected [1, {cuts[-1]}] logits for {space}, got {out.size} values")
            return np.array([seg.argmax() for seg in np.split(out, cuts[:-1])]).reshape(np.shape(space.nvec))
        if hasattr(space, "n"):
            if out.size != int(space.n):
                raise PolicyFailure(f"{self.name}: expected [1, {space.n}] logits for {space}, got {out.size} values")
            return int(space.start) + int(out.argmax())
        return out


def agent_of(made: Any, name: str) -> Any:
    """What ``made`` is as an agent (see the module), or one line saying what it is instead."""
    if callable(getattr(made, "act", None)):
        return made
    if callable(getattr(made, "predict", None)):
        return PredictAgent(made)
    if callable(made):
        return FunctionAgent(made)
    raise PolicyFailure(
        f"{name}: expected an agent with act(obs, info) or predict(obs, deterministic=...), or a function, "
        f"got {type(made).__name__}"
    )


def structure(space: Any) -> Any:
    """What must agree between an agent's space and the env's: the kind, shape, dtype, size and keys (not the
    bounds: an agent saved with a space's bounds rounded still reads its observations)."""
    sub = getattr(space, "spaces", None)
    if isinstance(sub, dict):
        return ("Dict", {k: structure(v) for k, v in sub.items()})
    if isinstance(sub, tuple):
        return ("Tuple", tuple(structure(v) for v in sub))
    nvec = getattr(space, "nvec", None)
    return (
        type(space).__name__,
        tuple(getattr(space, "shape", None) or ()),
        str(getattr(space, "dtype", "")),
        int(space.n) if hasattr(space, "n") and nvec is None else None,
        None if nvec is None else tuple(np.asarray(nvec).reshape(-1).tolist()),
    )


def mismatch(agent: Any, env: Any) -> bool:
    """Whether an agent's declared space cannot take (or give) the env's; an image agent's channels-first copy of
    the env's channels-last image (stable-baselines3's CnnPolicy saves it so) agrees."""
    if agent is None or structure(agent) == structure(env):
        return False
    shape, own = tuple(getattr(env, "shape", None) or ()), tuple(getattr(agent, "shape", None) or ())
    return not (len(shape) == 3 and own == (shape[2], shape[0], shape[1]) and str(agent.dtype) == str(env.dtype))


class NativeSlots(LockstepPolicy):
    """An agent over the env's own spaces in lockstep: one instance per slot (``make``), each reset with its
    rollout's seed and checked against its world's spaces; ``eps``: η2's ball for Box draws; ``warnings``: each
    step's warning level from its draws' η̂2 and MI (recorded; no action is taken on it: the env's action is the
    agent's)."""

    def __init__(self, name: str, make: Callable[[], Any], eps: float = 0.1, warnings: WarningConfig | None = None):
        self.name, self.make, self.eps, self.warnings = name, make, float(eps), warnings
        self.instances: dict[int, Any] = {}
        self.episodes: dict[int, list[int]] = {}  # slot → [seed, step]
        self.spaces: dict[int, tuple[Any, Any]] = {}
        self.instance(0)  # made here: an agent that cannot be made fails at build

    def instance(self, slot: int) -> Any:
        if slot not in self.instances:
            self.instances[slot] = agent_of(self.make(), self.name)
        return self.instances[slot]

    def reset(self, seed: int, slot: int = 0, world: Any = None) -> None:
        observations, actions = getattr(world, "observation_space", None), getattr(world, "action_space", None)
        if actions is None:
            raise PolicyFailure(f"{self.name}: {NOT_NATIVE}")
        agent = self.instance(slot)
        for what, own, env in (("observes", agent, observations), ("acts in", agent, actions)):
            declared = getattr(own, "observation_space" if what == "observes" else "action_space", None)
            if mismatch(declared, env):
                raise PolicyFailure(f"{self.name}: the agent {what} {declared}, but the env {what} {env}")
        self.spaces[slot], self.episodes[slot] = (observations, actions), [int(seed), 0]
        if callable(getattr(agent, "bind", None)):
            agent.bind(observations, actions)
        self._call(slot, "reset", lambda: agent.reset(int(seed)) if callable(getattr(agent, "reset", None)) else None)

    def act_batch(self, slots: Sequence[int], frames: Sequence[Any], infos: Sequence[dict]) -> list[Command]:
        commands = []
        for slot, obs, info in zip(slots, frames, infos):
            out = self._call(slot, "act", lambda: self.instance(slot).act(obs, dict(info)))  # noqa: B023
            where = f"{self.name} at seed {self.episodes[slot][0]}, step {self.episodes[slot][1]}"
            commands.append(self._command(where, out, self.spaces[slot][1]))
            self.episodes[slot][1] += 1
        return commands

    def _command(self, where: str, out: Any, space: Any) -> Command:
        action, draws = (out.env_action, out.draws) if isinstance(out, Action) else (out, None)
        if action is None:
            raise PolicyFailure(f"{where}: expected an action of {space}, got None")
        if draws is None:
            if self.warnings is not None:
                raise PolicyFailure(f"{where}: expected draws (warnings are on), got an action without")
            return Command(math.nan, math.nan, env_action=action)
        draws = np.asarray(draws, dtype=np.float64)
        eta2, within, mi, se, entropy = native_measures(where, action, draws, space, self.eps)
        level = -1
        if self.warnings is not None:
            c = self.warnings
            level = int(classify(eta2, 0.0 if math.isnan(mi) else mi, c.delta1, c.delta2, c.tau))
        return Command(
            math.nan, math.nan, env_action=action, eta2=eta2, mutual_information=mi, entropy=entropy,
            warning=level, draw_count=len(draws), mutual_information_se=se, eta2_counts=(within,),
            mi_stages=((len(draws), mi, se),),
        )  # fmt: skip

    def _call(self, slot: int, what: str, call: Callable[[], Any]) -> Any:
        """``call()``; an exception from the agent as one line with the seed and step (`PolicySlots._call`)."""
        return guarded(self.name, self.episodes.get(slot, [None, 0]), what, call)


def native_measures(
    where: str, action: Any, draws: np.ndarray, space: Any, eps: float
) -> tuple[float, int, float, float, float]:
    """(η̂2, draws that decide ``action``, MI, its SE, entropy) of an agent's ``draws``: class probabilities
    [n, C] of a Discrete(C) (MI and entropy from them), or action draws [n, *shape] of a Box (within ``eps`` in
    max-norm; no MI). Any other shape, or draws of another space, fails in one line."""
    if hasattr(space, "n") and not hasattr(space, "nvec"):
        n = int(space.n)
        ok = draws.ndim == 2 and draws.shape[1] == n and len(draws) and np.isfinite(draws).all()
        if not (ok and draws.min() >= 0 and np.abs(draws.sum(1) - 1).max() <= 1e-4):
            raise PolicyFailure(f"{where}: expected draws of [n, {n}] action probabilities, got shape {draws.shape}")
        within = int((draws.argmax(1) + int(space.start) == int(np.asarray(action).reshape(-1)[0])).sum())
        mi, se, entropy = draw_measures(draws)
        return within / len(draws), within, mi, se, entropy
    shape = tuple(getattr(space, "shape", None) or ())
    if hasattr(space, "nvec") or draws.shape[1:] != shape or not len(draws) or not np.isfinite(draws).all():
        raise PolicyFailure(f"{where}: expected draws [n, {', '.join(map(str, shape))}] of {space}, got {draws.shape}")
    gap = np.abs(draws - np.asarray(action, dtype=np.float64)).reshape(len(draws), -1).max(1)
    within = int((gap <= eps + 1e-9).sum())
    return within / len(draws), within, math.nan, math.nan, math.nan
