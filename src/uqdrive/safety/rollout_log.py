"""Append-only log of a cell's finished rollouts, so an interrupted cell resumes where it stopped.

One JSON line per rollout, written with a single ``write`` and flushed to disk as soon as the
rollout finishes; the first line holds the cell's identity hash, so a log written for another
config (model, world, estimator, seeds, code) is never resumed. A line cut short by an
interrupt is dropped on reading. Rollout i always uses seed base_seed + i and the estimators
consume outcomes in index order, so a resumed cell ends exactly as an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from uqdrive.files import atomic_path
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.safe_sets import PathVerdict

_ARRAY = "__ndarray__"


def _plain(value: object) -> object:
    if isinstance(value, PathVerdict):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        return {_ARRAY: value.dtype.str, "data": value.tolist()}
    return value.item() if isinstance(value, np.generic) else value


def _encode(result: RolloutResult) -> str:
    row = {f.name: _plain(getattr(result, f.name)) for f in dataclasses.fields(result)}
    return json.dumps(row)  # floats as repr: they read back bit for bit


def _decode(line: str) -> RolloutResult:
    row = json.loads(line)
    return RolloutResult(
        **{
            k: np.array(v["data"], dtype=v[_ARRAY]) if isinstance(v, dict) and _ARRAY in v else v
            for k, v in row.items()
            if k != "verdict"
        },
        verdict=PathVerdict(**row["verdict"]),
    )


class RolloutLog:
    """The rollouts of the cell with hash ``key``, kept at ``path``; rollout i has seed ``base_seed`` + i."""

    def __init__(self, path: str | Path, key: str, base_seed: int):
        self.path, self.key, self.base_seed = Path(path), str(key), int(base_seed)

    def load(self) -> list[RolloutResult]:
        """Rollouts 0 … m−1 kept by an earlier run of this cell; starts a fresh log otherwise.

        Keeps the longest run of complete lines whose seeds are base_seed + 0, 1, …; the file
        is rewritten to exactly those lines, so later appends continue a clean log.
        """
        lines = self.path.read_text().split("\n") if self.path.exists() else []
        kept: list[RolloutResult] = []
        valid_header = bool(lines) and _header_key(lines[0]) == self.key
        for line in lines[1:] if valid_header else []:
            try:
                result = _decode(line)
            except (ValueError, TypeError, KeyError):
                break
            if result.seed != self.base_seed + len(kept):
                break
            kept.append(result)
        with atomic_path(self.path) as tmp:
            tmp.write_text(
                "".join(line + "\n" for line in [json.dumps({"config_hash": self.key}), *lines[1 : 1 + len(kept)]])
            )
        return kept

    def append(self, result: RolloutResult) -> None:
        """Keep one finished rollout: one line, one write, flushed to disk before returning."""
        with self.path.open("a") as f:
            f.write(_encode(result) + "\n")
            f.flush()
            os.fsync(f.fileno())


def _header_key(line: str) -> str | None:
    try:
        header = json.loads(line)
    except ValueError:
        return None
    return header.get("config_hash") if isinstance(header, dict) else None
