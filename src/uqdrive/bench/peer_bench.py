"""`uqdrive bench peer`: episodes that PyDSMC and uqdrive take to answer one question about one agent in one env:
"η1 ≥ eta?" with error ≤ γ and indifference θ (certified: η1 > eta − θ; refuted: η1 < eta + θ).

The env is uqdrive's roundabout as a Gymnasium env (``uqdrive/Roundabout-v0``, truncated at ``--horizon`` steps), the
agent a fixed steering command (action ``[steer]``), an episode safe while no step's info reports a collision or
leaving the road. uqdrive: `uqdrive certify` in the world ``uqdrive_roundabout`` (its sequential threshold test,
exact error, a look every ``--look-size`` episodes). PyDSMC (``pydsmc``, `pip install 'uqdrive[peer]'`): a custom
binomial property with its sound method (Clopper–Pearson to half-width θ at confidence 1 − γ), evaluated in runs of
``--look-size`` episodes until it converges; its estimate ≥ eta is its "certified" (η1 > eta − θ with probability
≥ 1 − γ), below it "refuted". Prints both answers and ``RESULT peer episodes_ratio=<PyDSMC / uqdrive>``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import torch

ENV_ID = "uqdrive/Roundabout-v0"
PYDSMC_MISSING = "uqdrive bench peer needs PyDSMC, which is not installed: pip install 'uqdrive[peer]'"


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

    policy = folder / "steer.pt"
    torch.jit.save(torch.jit.script(_Steer(args.steer)), str(policy))
    flags = [f"--eta={args.eta}", f"--theta={args.theta}", f"--gamma={args.gamma}", f"--look-size={args.look_size}"]
    argv = ["--policy", str(policy), "--world", "uqdrive_roundabout", "--root", str(folder), "--no-progress", *flags]
    argv += [f"--budget={args.budget}", "--out", str(folder / "certify.json")]
    argv.append(f"gym_world.horizon_steps={args.horizon}")
    record = run_certify(compose_certify(parse(argv)))
    return {"verdict": record.verdict, "episodes": record.rollouts, "eta1_hat": record.eta1_hat}


def pydsmc_answer(args: argparse.Namespace) -> dict:
    """PyDSMC's estimate of the same agent's η1 in the same env, read as a verdict."""
    try:
        import pydsmc
    except ImportError:
        raise SystemExit(PYDSMC_MISSING) from None
    import gymnasium

    import uqdrive.sim.gym_env  # noqa: F401  (registers uqdrive/Roundabout-v0)

    def safe(_property, trajectory) -> float:
        return float(not any(step[5].get("collision") or step[5].get("off_road") for step in trajectory))

    prop = pydsmc.create_custom_property(
        "safe", safe, epsilon=args.theta, kappa=args.gamma, bounds=(0, 1), binomial=True, sound=True
    )
    env = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make(ENV_ID, max_episode_steps=args.horizon)])
    evaluator = pydsmc.Evaluator(env, log_dir=None, log_level=40)
    evaluator.register_property(prop)
    action = np.full((1, 1), args.steer, np.float32)
    evaluator.eval(
        predict_fn=lambda obs, *_, **__: (np.repeat(action, len(obs), axis=0), None),
        num_initial_episodes=args.look_size,
        num_episodes_per_policy_run=args.look_size,
        episode_limit=args.pydsmc_limit,
        num_threads=1,
    )
    env.close()
    verdict = ("certified" if prop.mean >= args.eta else "refuted") if prop.converged() else "undecided"
    return {"verdict": verdict, "episodes": prop.num_episodes, "eta1_hat": prop.mean}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench peer", description=__doc__)
    ap.add_argument("--steer", type=float, default=0.15, help="the agent's fixed steering command, in [-1, 1]")
    ap.add_argument("--horizon", type=int, default=30, help="episode length in steps (15 a second)")
    ap.add_argument("--eta", type=float, default=0.9, help="the question: eta1 >= this?")
    ap.add_argument("--theta", type=float, default=0.05, help="indifference half-width (PyDSMC: its epsilon)")
    ap.add_argument("--gamma", type=float, default=0.05, help="error probability (PyDSMC: its kappa)")
    ap.add_argument("--look-size", type=int, default=4, help="episodes between looks, both tools")
    ap.add_argument("--budget", type=int, default=2000, help="uqdrive's most episodes")
    ap.add_argument("--pydsmc-limit", type=int, default=5000, help="PyDSMC's most episodes")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        ours = uqdrive_answer(args, Path(folder))
    theirs = pydsmc_answer(args)
    print(f"question: eta1 >= {args.eta:g}? (theta={args.theta:g}, gamma={args.gamma:g}) for steer {args.steer:g} "
          f"in {ENV_ID}, {args.horizon} steps")  # fmt: skip
    for name, answer in (("uqdrive", ours), ("PyDSMC", theirs)):
        print(f"{name:>8}: {json.dumps(answer)}")
    print(
        f"RESULT peer episodes_ratio={theirs['episodes'] / ours['episodes']:.2f} pydsmc_episodes={theirs['episodes']} "
        f"uqdrive_episodes={ours['episodes']} pydsmc_verdict={theirs['verdict']} uqdrive_verdict={ours['verdict']} "
        f"same_verdict={str(theirs['verdict'] == ours['verdict']).lower()}"
    )
    return 0
