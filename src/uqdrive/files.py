"""Output files that are never half-written: an interrupted stage leaves the old file or none."""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary sibling of `path`; rename it onto `path` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


MISSING = "–"  # a CSV's missing value (a mean over no frames): what the report prints, never "nan"


def _no_nan(data: object) -> object:
    """NaN as null: JSON has no NaN, and a reader that is not Python's fails on it."""
    if isinstance(data, float) and math.isnan(data):
        return None
    if isinstance(data, dict):
        return {k: _no_nan(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [_no_nan(v) for v in data]
    return data


def write_json(path: str | Path, data: object, sort_keys: bool = True) -> None:
    """``data`` as JSON, NaN written as null (strict JSON: no NaN token reaches a file)."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(_no_nan(data), indent=2, sort_keys=sort_keys, allow_nan=False) + "\n")


def write_csv(path: str | Path, rows: list[dict]) -> Path:
    """Rows (dicts with the same keys, in column order) as a CSV with a header, written atomically."""
    path = Path(path)
    if not rows:
        raise ValueError(f"{path}: no rows to write")
    with atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows({k: _cell(v) for k, v in row.items()} for row in rows)
    return path


def _cell(value: object) -> object:
    """A CSV cell: a missing value (None, NaN) as ``MISSING``."""
    return MISSING if value is None or (isinstance(value, float) and math.isnan(value)) else value
