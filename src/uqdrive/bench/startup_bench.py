"""`uqdrive bench startup`: how soon `uqdrive certify` answers — its `--help`, a refused flag, its first rollout —
each a fresh process, against a bare Python's start measured in the same run.

``help_s``: `uqdrive certify --help` (and the other commands' help, the slowest of them as ``other_help_s``);
``refuse_s``: `uqdrive certify --policy P --eta 1.5` refused (exit 2); ``first_rollout_s``: from the start of a
certify run (a policy going straight, a small budget, fixed seeds, its own folder) until the rollout log holds its
first rollout. Each the median of ``--repeats`` runs; ratios over ``python_s`` (`python -c pass`). Prints
``RESULT startup help_s=… refuse_s=… first_rollout_s=… …``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

COMMAND = [sys.executable, "-m", "uqdrive.tools.cli"]
OTHERS = ("findings", "headline", "replay", "redecide", "bound")


def seconds(argv: list[str], code: int | None = 0) -> float:
    """Wall seconds of one fresh process; its exit status checked."""
    start = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True)
    took = time.perf_counter() - start
    if code is not None and done.returncode != code:
        raise SystemExit(f"{' '.join(argv)} exited {done.returncode}, expected {code}: {done.stderr.strip()[-300:]}")
    return took


def first_rollout(folder: Path) -> float:
    """Seconds until a certify run's rollout log holds one rollout (the run then left to finish)."""
    import torch

    class Straight(torch.nn.Module):
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return torch.zeros((x.shape[0], 1))

    policy = folder / "straight.pt"
    torch.jit.save(torch.jit.script(Straight()), str(policy))
    out = folder / "run"
    argv = [*COMMAND, "certify", "--policy", str(policy), "--out-dir", str(out), "--no-progress"]
    argv += ["--eta", "0.5", "--gamma", "0.1", "--budget", "8", "--look-size", "4", "--seed-base", "0"]
    argv += ["--horizon", "3"]
    start = time.perf_counter()
    process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    took = None
    while process.poll() is None or took is None:
        logs = list((out / "cache" / "rollouts" / "certify").glob("*.jsonl"))
        if took is None and logs and logs[0].read_text().count("\n") >= 2:
            took = time.perf_counter() - start
        if process.poll() is not None and took is None:
            raise SystemExit(f"the certify run ended without a rollout: {process.stderr.read()[-300:]}")
        time.sleep(0.02)
    return took


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench startup", description=__doc__)
    ap.add_argument("--repeats", type=int, default=3, help="fresh processes per measurement (the median is kept)")
    args = ap.parse_args(argv)

    def median(run) -> float:
        return statistics.median(run() for _ in range(args.repeats))

    python_s = median(lambda: seconds([sys.executable, "-c", "pass"]))
    top_s = median(lambda: seconds([*COMMAND, "--help"]))
    help_s = median(lambda: seconds([*COMMAND, "certify", "--help"]))
    refuse_s = median(lambda: seconds([*COMMAND, "certify", "--policy", "x.pt", "--eta", "1.5"], code=2))
    other_s = max(median(lambda n=name: seconds([*COMMAND, n, "--help"])) for name in OTHERS)
    with tempfile.TemporaryDirectory() as folder:
        rollout_s = first_rollout(Path(folder))
    print(
        f"RESULT startup help_s={help_s:.2f} refuse_s={refuse_s:.2f} first_rollout_s={rollout_s:.2f} "
        f"uqdrive_help_s={top_s:.2f} other_help_s={other_s:.2f} python_s={python_s:.2f} "
        f"help_over_python={help_s / python_s:.1f} refuse_over_python={refuse_s / python_s:.1f}"
    )
    return 0
