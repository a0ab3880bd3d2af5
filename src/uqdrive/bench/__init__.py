"""`uqdrive bench NAME`: speed benchmarks that print a ratio against a baseline measured in the same run.

Every benchmark is a module ``uqdrive.bench.<name>_bench`` with ``main(argv) -> int`` whose last
printed line is ``RESULT <name> key=value ...``.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

SUFFIX = "_bench"  # a benchmark's module: uqdrive.bench.<name>_bench


def available() -> list[str]:
    return sorted(m.name.removesuffix(SUFFIX) for m in pkgutil.iter_modules(__path__) if m.name.endswith(SUFFIX))


def main(argv: list[str]) -> int:
    names = available()
    if not argv or argv[0] in {"-h", "--help"}:
        print("usage: uqdrive bench NAME [ARGS...]\n\nbenchmarks: " + ", ".join(names))
        return 0
    name, rest = argv[0], argv[1:]
    if name not in names:
        print(f"uqdrive bench: unknown benchmark {name!r}; choose one of {names}", file=sys.stderr)
        return 2
    return int(importlib.import_module(f"uqdrive.bench.{name}{SUFFIX}").main(rest) or 0)
