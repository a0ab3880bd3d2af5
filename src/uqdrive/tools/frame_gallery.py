"""``uqdrive frames``: one example camera frame per weather, to eyeball the simulator.

Writes ``<weather>.png`` (camera resolution, RGB) and ``weathers.png``: the weathers side
by side, top row as rendered, bottom row as the network sees it (grey 64x48), enlarged.
``--compare-render 160x120`` writes instead ``resolution.png`` and ``resolution.json``: the
network's input at the configured render size against that one (`uqdrive.tools.resolution`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from uqdrive.network_input import preprocess_frame
from uqdrive.sim.autopilot import Autopilot
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import ScenarioConfig, WeatherConfig, find_conf
from uqdrive.sim.env import DrivingEnv

WEATHERS = ("clear_noon", "afternoon", "rain", "fog")


def _size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--compare-render={text!r} must be WIDTHxHEIGHT, e.g. 160x120") from None
    if width < 8 or height < 8:
        raise argparse.ArgumentTypeError(f"--compare-render={text!r}: width and height must be >= 8")
    return width, height


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="uqdrive frames", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/frames", help="output folder (default: docs/frames)")
    parser.add_argument("--scenario", default="obstacle", help="scenario yaml name in conf/scenario/")
    parser.add_argument(
        "--seed", type=int, default=0, help="episode seed (the autopilot's, and the first of --episodes)"
    )
    parser.add_argument("--time", type=float, default=2.0, help="seconds of autopilot driving before the snapshot")
    parser.add_argument("--noise", type=float, default=0.0, help="pixel noise sigma (fraction of full intensity)")
    parser.add_argument("--conf", type=Path, default=None, help="Hydra conf/ folder (default: found from the repo)")
    parser.add_argument(
        "--compare-render",
        metavar="WxH",
        type=_size,
        default=None,
        help="compare the network's input rendered at WxH (then reduced) with the configured size",
    )
    parser.add_argument("--episodes", type=int, default=4, help="--compare-render: autopilot episodes per scenario")
    parser.add_argument("--every", type=int, default=5, help="--compare-render: every n-th step of an episode")
    parser.add_argument(
        "--sigma",
        type=float,
        default=0.05,
        help="--compare-render: sensor noise whose standard deviation on the network's input is reported",
    )
    return parser.parse_args(argv)


def weather_tile(env: DrivingEnv, scenario: ScenarioConfig, weather: WeatherConfig, args, out: Path) -> np.ndarray:
    """The camera frame after ``args.time`` s of autopilot driving in ``weather`` (written as <weather>.png), and
    a tile of it above the network's grey input, both shown at least 160x120."""
    obs = env.reset(args.seed, Condition(scenario, weather, args.noise))
    pilot = Autopilot(env.route, env.vehicle_config, control_hz=env.control_hz, seed=args.seed)
    info = env.last_info
    while info["t"] < args.time - 1e-9 and not info["done"]:
        action = pilot.act(info)
        obs, info = env.step(action.steer, action.speed)
    bgr = np.ascontiguousarray(obs[..., ::-1])
    cv2.imwrite(str(out / f"{weather.name}.png"), bgr)
    h, w = 120, 160
    grey = cv2.resize(preprocess_frame(obs), (w, h), interpolation=cv2.INTER_NEAREST)
    tile = np.vstack([cv2.resize(bgr, (w, h), interpolation=cv2.INTER_NEAREST), cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)])
    cv2.putText(tile, weather.name, (3, 11), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
    return tile


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    conf = args.conf or find_conf()
    if args.compare_render:
        from uqdrive.tools.resolution import write

        seeds = range(args.seed, args.seed + args.episodes)
        result = write(Path(args.out), conf, args.compare_render, seeds, args.every, args.sigma)
        print(
            f"wrote resolution.png and resolution.json to {args.out} ({result['configured']} against "
            f"{result['reference']})"
        )
        return 0
    scenario = ScenarioConfig.from_yaml(conf / "scenario" / f"{args.scenario}.yaml")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with DrivingEnv() as env:
        weathers = [WeatherConfig.from_yaml(conf / "weather" / f"{name}.yaml") for name in WEATHERS]
        tiles = [weather_tile(env, scenario, weather, args, out) for weather in weathers]
    cv2.imwrite(str(out / "weathers.png"), np.hstack(tiles))
    print(f"wrote {len(WEATHERS) + 1} images to {out}")
    return 0
