"""`uqdrive bench NAME`: speed benchmarks that print a ratio against a baseline measured in the same run.

Every benchmark is a module ``uqdrive.bench.<name>`` (or ``<name>_bench``, where ``<name>`` is another module's
name in the package) with ``main(argv) -> int`` whose last printed line is ``RESULT <name> key=value ...``.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys


def _modules() -> dict[str, str]:
    """Benchmark name → its module's name."""
    return {m.name.removesuffix("_bench"): m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")}


def available() -> list[str]:
    return sorted(_modules())


def main(argv: list[str]) -> int:
    names = available()
    if not argv or argv[0] in {"-h", "--help"}:
        print("usage: uqdrive bench NAME [ARGS...]\n\nbenchmarks: " + ", ".join(names))
        return 0
    name, rest = argv[0], argv[1:]
    if name not in names:
        print(f"uqdrive bench: unknown benchmark {name!r}; choose one of {names}", file=sys.stderr)
        return 2
    return int(importlib.import_module(f"uqdrive.bench.{_modules()[name]}").main(rest) or 0)
