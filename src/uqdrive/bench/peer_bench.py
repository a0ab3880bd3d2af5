"""`uqdrive bench peer`: episodes that PyDSMC and uqdrive take to answer one question about one agent in one env:
"η1 ≥ eta?" with error ≤ γ and indifference θ (certified: η1 > eta − θ; refuted: η1 < eta + θ).

The env (``--world``): uqdrive's roundabout as a Gymnasium env (``uqdrive/Roundabout-v0``, world
``uqdrive_roundabout``), or HighwayEnv's roundabout (``highway_roundabout``: ``roundabout-v0`` behind uqdrive's hooks,
handed to PyDSMC as `WorldEnv`, the very env, hooks and safe set the certify run drives), truncated at
``--horizon`` steps. The agent: a fixed steering command (action ``[steer]``) at the cruise speed; an episode is
safe while every step keeps the world's safe set (its ``safe_if``; uqdrive's roundabout: no collision, on the
road). uqdrive: `uqdrive certify` in that world (its sequential threshold test, exact error, a look every
``--look-size`` episodes). PyDSMC (``pydsmc``, `pip install 'uqdrive[peer]'`): a custom
binomial property with its sound method (Clopper–Pearson to half-width θ at confidence 1 − γ), evaluated in runs of
``--look-size`` episodes until it converges; its estimate ≥ eta is its "certified" (η1 > eta − θ with probability
≥ 1 − γ), below it "refuted". Prints both answers and ``RESULT peer episodes_ratio=<PyDSMC / uqdrive>``.

Or any agent in any env as it is (``--policy FILE --env ID`` with certify's ``--unsafe-if``, ``--terminated``,
``--safe-when``, ``--env-kwargs``; ``--horizon``: its most steps): certify's own loader builds the agent
(`uqdrive.policy.native`) and the world both tools drive (PyDSMC indexes observations as arrays: a Box observation).

``--grid``: no env — a synthetic agent of exact η1 on a grid 0.5 … 1 (`uqdrive.bench.peer_grid`), both tools'
expected and worst episodes; prints ``RESULT peer ratio_min=… ratio_median=… ratio_at_target=…``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import torch

from uqdrive.policy.interface import Action
from uqdrive.sim.gym_world import GymWorld

ENV_ID = "uqdrive/Roundabout-v0"
WORLDS = ("uqdrive_roundabout", "highway_roundabout")
CRUISE = 6.0  # m/s: the speed of a policy file's actions, which give none (`uqdrive certify`'s default)
PYDSMC_MISSING = "uqdrive bench peer needs PyDSMC, which is not installed: pip install 'uqdrive[peer]'"


class WorldEnv(gymnasium.Env):
    """A uqdrive Gymnasium world as a plain env: action [steer] at a fixed ``speed``, the world's frame as the
    observation, its info (the hooks' state and the env's scalars, what the safe set reads) as the info; an
    episode ends where the world ends it (the safe set broken, the env done, the horizon)."""

    def __init__(self, world: GymWorld, speed: float, agent: Any = None):
        self.world, self.speed, self.agent = world, speed, agent
        self.action_space = world.action_space or gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = world.observation_space or gymnasium.spaces.Box(0, 255, (48, 64, 3), np.uint8)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        seed = int(self.np_random.integers(2**31)) if seed is None else seed
        obs = self.world.reset(seed)
        if self.agent is not None:
            self.agent.reset(seed, slot=0, world=self.world)
        return obs, dict(self.world.last_info)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self.world.action_space is not None:  # the env as it is: the agent's own action
            frame, info = self.world.apply(Action(env_action=action))
        else:
            frame, info = self.world.step(float(np.asarray(action).ravel()[0]), self.speed)
        return frame, 0.0, self.world.done, False, info

    def decide(self, obs: Any) -> np.ndarray:
        """The agent's actions for a vector env's batch of observations ``obs`` (one per env)."""
        batch = gymnasium.vector.utils.batch_space(self.observation_space, 1)  # PyDSMC's vector env holds one env
        items = gymnasium.vector.utils.iterate(batch, obs)
        return np.array([c.env_action for c in self.agent.act_batch([0], list(items), [dict(self.world.last_info)])])

    def close(self) -> None:
        self.world.close()


class _Steer(torch.nn.Module):
    """The fixed agent as a TorchScript policy for `uqdrive certify`: steering [B, 1], whatever the frame."""

    def __init__(self, steer: float):
        super().__init__()
        self.steer = steer

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.full((x.shape[0], 1), self.steer)


def uqdrive_answer(args: argparse.Namespace, folder: Path) -> dict:
    """`uqdrive certify` of the fixed agent: its verdict, episodes and estimate."""
    from uqdrive.pipeline.certify_stage import compose_certify, parse, run_certify

    flags = [f"--eta={args.eta}", f"--theta={args.theta}", f"--gamma={args.gamma}", f"--look-size={args.look_size}"]
    argv = [*_where(args, folder), "--out-dir", str(folder), "--no-progress", *flags]
    argv += ["--seed-base", "0"]  # fixed seeds, the full gamma, no ledger: what PyDSMC does
    argv += [f"--budget={args.budget}", "--out", str(folder / "certify.json")]
    record = run_certify(compose_certify(parse(argv)))
    return {"verdict": record.verdict, "episodes": record.rollouts, "eta1_hat": record.eta1_hat}


def _where(args: argparse.Namespace, folder: Path) -> list[str]:
    """certify's flags for the agent and world: ``--policy`` in ``--env`` with its signals, else the fixed steering
    command (saved here) in ``--world``."""
    if args.env is not None:
        signals = [f"--unsafe-if={key}" for key in args.unsafe_if] + [f"--terminated={args.terminated}"]
        signals += [f"--safe-when={args.safe_when}", f"--env-kwargs={args.env_kwargs}", f"--steps={args.horizon}"]
        return ["--policy", str(Path(args.policy).resolve()), "--env", args.env, *signals]
    policy = folder / "steer.pt"
    if not policy.exists():
        torch.jit.save(torch.jit.script(_Steer(args.steer)), str(policy))
    return ["--policy", str(policy), "--world", args.world, f"gym_world.horizon_steps={args.horizon}"]


def world_env(args: argparse.Namespace, folder: Path) -> tuple[Any, Callable[[dict], bool]]:
    """PyDSMC's env for ``--world`` (or ``--env``, with the agent: certify's own loader) and whether one step's
    info keeps the safe set."""
    if args.env is not None:
        from uqdrive.pipeline.certify_stage import CertifyStage, compose_certify, parse
        from uqdrive.policy.policy_files import load_policy
        from uqdrive.schema import validate

        config = validate(CertifyStage, compose_certify(parse(_where(args, folder)))).gym_world
        agent = load_policy(args.policy, native=True).build(float(config.control_hz))
        env = WorldEnv(GymWorld(config), CRUISE, agent)
        return env, lambda info: not info["unsafe"] and all(info[k] == v for k, v in config.safe_if.items())
    if args.world == "uqdrive_roundabout":
        import uqdrive.sim.gym_env  # noqa: F401  (registers uqdrive/Roundabout-v0)

        env = gymnasium.make(ENV_ID, max_episode_steps=args.horizon)
        return env, lambda info: not (info.get("collision") or info.get("off_road"))
    from uqdrive.pipeline.certify_stage import CertifyStage, compose_certify, parse
    from uqdrive.schema import validate

    config = validate(CertifyStage, compose_certify(parse(_where(args, folder)))).gym_world
    return WorldEnv(GymWorld(config), CRUISE), lambda info: all(info[k] == v for k, v in config.safe_if.items())


def pydsmc_answer(args: argparse.Namespace, folder: Path) -> dict:
    """PyDSMC's estimate of the same agent's η1 in the same env, read as a verdict."""
    try:
        import pydsmc
    except ImportError:
        raise SystemExit(PYDSMC_MISSING) from None

    env, safe_step = world_env(args, folder)

    def safe(_property, trajectory) -> float:
        return float(all(safe_step(step[5]) for step in trajectory))

    prop = pydsmc.create_custom_property(
        "safe", safe, epsilon=args.theta, kappa=args.gamma, bounds=(0, 1), binomial=True, sound=True
    )
    vector = gymnasium.vector.SyncVectorEnv([lambda: env])
    evaluator = pydsmc.Evaluator(vector, log_dir=None, log_level=40)
    evaluator.register_property(prop)
    action = np.full((1, 1), args.steer, np.float32)

    def predict(obs: Any, *_: Any, **__: Any) -> tuple[np.ndarray, None]:
        return (env.decide(obs) if args.env is not None else np.repeat(action, len(obs), axis=0)), None

    evaluator.eval(
        predict_fn=predict,
        num_initial_episodes=args.look_size,
        num_episodes_per_policy_run=args.look_size,
        episode_limit=args.pydsmc_limit,
        num_threads=1,
    )
    vector.close()
    verdict = ("certified" if prop.mean >= args.eta else "refuted") if prop.converged() else "undecided"
    return {"verdict": verdict, "episodes": prop.num_episodes, "eta1_hat": prop.mean}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench peer", description=__doc__)
    ap.add_argument("--world", choices=WORLDS, default=WORLDS[0], help="the env both tools drive")
    ap.add_argument("--steer", type=float, default=0.15, help="the agent's fixed steering command, in [-1, 1]")
    ap.add_argument("--policy", help="an agent file (with --env: what `uqdrive certify --policy` takes)")
    ap.add_argument("--env", help="a Gymnasium env id driven as it is (`uqdrive certify --env`), in place of --world")
    ap.add_argument("--unsafe-if", action="append", default=[], help="with --env: info KEY true is unsafe")
    ap.add_argument("--terminated", choices=("end", "unsafe"), default="end", help="with --env: a termination is")
    ap.add_argument("--safe-when", default="", help="with --env: module:function(obs, info) -> bool")
    ap.add_argument("--env-kwargs", default="{}", help="with --env: gymnasium.make's kwargs as JSON")
    ap.add_argument("--horizon", type=int, default=30, help="episode length in steps (15 a second)")
    ap.add_argument("--eta", type=float, default=0.9, help="the question: eta1 >= this?")
    ap.add_argument("--theta", type=float, default=0.05, help="indifference half-width (PyDSMC: its epsilon)")
    ap.add_argument("--gamma", type=float, default=0.05, help="error probability (PyDSMC: its kappa)")
    ap.add_argument("--look-size", type=int, default=4, help="episodes between looks, both tools")
    ap.add_argument("--budget", type=int, default=2000, help="uqdrive's most episodes")
    ap.add_argument("--pydsmc-limit", type=int, default=5000, help="PyDSMC's most episodes")
    ap.add_argument("--grid", action="store_true", help="a synthetic agent over every eta1 0.5 ... 1, no env")
    ap.add_argument("--reps", type=int, default=50, help="--grid: simulated runs per eta1 (each tool's worst)")
    ap.add_argument("--seed", type=int, default=0, help="--grid: the simulated episodes' seed")
    args = ap.parse_args(argv)
    if args.grid:
        from uqdrive.bench.peer_grid import grid, report

        print(f"question: eta1 >= {args.eta:g}? (theta={args.theta:g}, gamma={args.gamma:g}), a look every "
              f"{args.look_size}, uqdrive's budget {args.budget}, {args.reps} runs per eta1")  # fmt: skip
        print(report(grid(args), args.eta))
        return 0
    if (args.env is None) != (args.policy is None):
        ap.error("--policy and --env go together (an agent in an env as it is)")
    with tempfile.TemporaryDirectory() as folder:
        ours = uqdrive_answer(args, Path(folder))
        theirs = pydsmc_answer(args, Path(folder))
    agent = args.policy or f"steer {args.steer:g}"
    print(f"question: eta1 >= {args.eta:g}? (theta={args.theta:g}, gamma={args.gamma:g}) for {agent} "
          f"in {args.env or args.world}, {args.horizon} steps")  # fmt: skip
    for name, answer in (("uqdrive", ours), ("PyDSMC", theirs)):
        print(f"{name:>8}: {json.dumps(answer)}")
    print(
        f"RESULT peer episodes_ratio={theirs['episodes'] / ours['episodes']:.2f} pydsmc_episodes={theirs['episodes']} "
        f"uqdrive_episodes={ours['episodes']} pydsmc_verdict={theirs['verdict']} uqdrive_verdict={ours['verdict']} "
        f"same_verdict={str(theirs['verdict'] == ours['verdict']).lower()}"
    )
    return 0
