"""`uqdrive bench gym_step`: a closed-loop step through the Gymnasium adapter (`GymWorld.step`: the env's step,
then its state read, the info the safe set judges recorded, the frame converted to the network's with sensor
noise) against the env's own ``step`` in the same run, from the same seeds, with the same commands.

``--world highway``: HighwayEnv's roundabout (conf/gym_world/highway_roundabout.yaml) driven by its own expert;
``--world uqdrive``: uqdrive's own ``uqdrive/Roundabout-v0`` through the ``info`` hooks, steered by a sinusoid.
Commands are recorded once through the adapter (episodes restart with seed + 1, … as they end), then replayed in
alternating repeats: the env's own step given the action the adapter would send (the same dynamics), and the
adapter's. Times are CPU seconds of this process; the median ratio is reported. Target: adapter/env <= 1.1.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

from uqdrive.sim.condition import Condition
from uqdrive.sim.config import GymWorldConfig, find_conf
from uqdrive.sim.gym_world import GymWorld

Commands = list[tuple[int, list[tuple[float, float]]]]  # (episode seed, its (steer, speed) commands)


def world_config(world: str) -> GymWorldConfig:
    if world == "highway":
        return GymWorldConfig.from_yaml(find_conf() / "gym_world" / "highway_roundabout.yaml")
    return GymWorldConfig(env_id="uqdrive/Roundabout-v0", env_kwargs={"speed_action": True}, horizon_steps=600)


def record_commands(world: GymWorld, steps: int, seed: int, noise: float, expert: bool) -> Commands:
    """``steps`` commands in episodes seed, seed + 1, …: the env's expert's, or a slow sinusoid at 6 m/s."""
    episodes: Commands = []
    total = 0
    while total < steps:
        episode_seed = seed + len(episodes)
        world.reset(episode_seed, Condition(world.config, None, noise))
        commands: list[tuple[float, float]] = []
        while not world.done and total < steps:
            command = world.expert_command() if expert else (0.3 * math.sin(0.2 * total), 6.0)
            world.step(*command)
            commands.append(command)
            total += 1
        episodes.append((episode_seed, commands))
    return episodes


def time_env(world: GymWorld, episodes: Commands) -> float:
    """CPU seconds of the env's own reset and step, given the actions the adapter would send."""
    start = time.process_time()
    for episode_seed, commands in episodes:
        world.env.reset(seed=episode_seed)
        for steer, speed in commands:
            world.env.step(world.hooks.action(steer, speed))
    return time.process_time() - start


def time_adapter(world: GymWorld, episodes: Commands, noise: float) -> float:
    """CPU seconds of the adapter's reset and step, frames rendered (the network's input) with sensor noise."""
    start = time.process_time()
    for episode_seed, commands in episodes:
        world.reset(episode_seed, Condition(world.config, None, noise))
        for steer, speed in commands:
            world.step(steer, speed)
    return time.process_time() - start


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench gym_step", description=__doc__)
    ap.add_argument("--world", choices=("highway", "uqdrive"), default="highway", help="the env stepped")
    ap.add_argument("--steps", type=int, default=300, help="steps per timing")
    ap.add_argument("--repeats", type=int, default=3, help="alternating timings; the median ratio is reported")
    ap.add_argument("--noise", type=float, default=0.05, help="sensor noise sigma on the network's frame")
    ap.add_argument("--seed", type=int, default=0, help="seed of the first recorded episode")
    args = ap.parse_args(argv)
    with GymWorld(world_config(args.world)) as world:
        episodes = record_commands(world, args.steps, args.seed, args.noise, expert=args.world == "highway")
        time_adapter(world, episodes[:1], args.noise)  # warm-up
        env_s, adapter_s = [], []
        for _ in range(args.repeats):
            env_s.append(time_env(world, episodes))
            adapter_s.append(time_adapter(world, episodes, args.noise))
    ratio = statistics.median(a / e for a, e in zip(adapter_s, env_s))
    steps = sum(len(c) for _, c in episodes)
    print(f"{world.config.env_id}, noise {args.noise:g}, {steps} steps in {len(episodes)} episodes x {args.repeats}")
    print(f"env step:     {steps / statistics.median(env_s):7.1f} steps/s")
    print(
        f"adapter step: {steps / statistics.median(adapter_s):7.1f} steps/s   adapter/env {ratio:.2f}x (target <= 1.1)"
    )
    print(f"RESULT gym_step adapter_over_env={ratio:.2f}")
    return 0
