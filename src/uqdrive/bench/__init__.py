"""`uqdrive bench NAME`: speed benchmarks that print a ratio against a baseline measured in the same run.

Every benchmark is a module ``uqdrive.bench.<name>_bench`` with ``main(argv) -> int`` whose last
printed line is ``RESULT <name> key=value ...``.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import pkgutil
import re
import sys
from pathlib import Path

SUFFIX = "_bench"  # a benchmark's module: uqdrive.bench.<name>_bench


def available() -> list[str]:
    return sorted(m.name.removesuffix(SUFFIX) for m in pkgutil.iter_modules(__path__) if m.name.endswith(SUFFIX))


def summary(name: str) -> str:
    """What benchmark ``name`` measures: the first clause of its module's docstring, read from the source (importing
    a benchmark loads torch and pybullet, seconds each)."""
    spec = importlib.util.find_spec(f"{__name__}.{name}{SUFFIX}")
    doc = ast.get_docstring(ast.parse(Path(spec.origin).read_text(encoding="utf8"))) or ""
    text = " ".join(doc.split()).split("`: ", 1)[-1]
    return re.split(r", | \(|; |\. ", text, maxsplit=1)[0].rstrip(".")


def main(argv: list[str]) -> int:
    names = available()
    if not argv or argv[0] in {"-h", "--help"}:
        width = max(map(len, names))
        lines = [f"  {name:<{width}}  {summary(name)}" for name in names]
        print("usage: uqdrive bench NAME [ARGS...]\n\nbenchmarks:\n" + "\n".join(lines))
        print("\n`uqdrive bench NAME --help` says what a benchmark takes and prints.")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in names:
        print(f"uqdrive bench: unknown benchmark {name!r}; choose one of {names}", file=sys.stderr)
        return 2
    return int(importlib.import_module(f"uqdrive.bench.{name}{SUFFIX}").main(rest) or 0)
