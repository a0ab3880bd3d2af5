"""The `uqdrive` command: small utilities beside the DVC stages.

Each subcommand lives in the module that owns its logic and exposes ``main(argv)``;
this file only routes, so importing it stays cheap (no torch or pybullet until needed).
"""

from __future__ import annotations

import importlib
import sys

COMMANDS: dict[str, tuple[str, str]] = {
    "bench": ("uqdrive.bench", "speed benchmarks; `uqdrive bench --help` lists them"),
    "bound": ("uqdrive.uq.bound_table", "sample counts of each estimation scheme for (theta, gamma)"),
    "certify": (
        "uqdrive.pipeline.certify_stage",
        "certify a policy file's eta1 >= target in a world, or refuse (exit 0 only if certified)",
    ),
    "findings": ("uqdrive.report.findings_text", "print metrics/findings.json as the report states it"),
    "headline": ("uqdrive.report.headline", "print metrics/summary.json as the README's results table"),
    "frames": ("uqdrive.tools.frame_gallery", "write one example camera frame per weather to docs/"),
    "redecide": ("uqdrive.analysis.redecide", "re-decide a findings file's recorded counts with the current tests"),
    "replay": (
        "uqdrive.pipeline.replay_stage",
        "re-drive one rollout of a safety cell exactly and write it as a clip (MP4, GIF)",
    ),
    "plots-page": ("uqdrive.tools.plots_page", "write the page `dvc plots show` fills, its scripts inlined (no CDN)"),
}


def _usage() -> str:
    width = max(map(len, COMMANDS))
    lines = ["usage: uqdrive [--version] COMMAND [ARGS...]", "", "commands:"]
    lines += [f"  {name:<{width}}  {help_}" for name, (_, help_) in COMMANDS.items()]
    lines += ["", "`uqdrive COMMAND --help` says what a command takes."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help"}:
        print(_usage())
        return 0
    if argv[0] in {"-V", "--version"}:
        from uqdrive import __version__

        print(f"uqdrive {__version__}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"uqdrive: unknown command {name!r}; choose one of {sorted(COMMANDS)}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[name][0])
    return int(module.main(rest) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
