"""Typed records: what one stage writes and another reads (a safety cell, an avoid result, a trained controller's
metrics, the findings, the report's headline), each a frozen dataclass declared beside the code that computes it.

`write_record` is the one writer of every stage's metrics file; `read_record` gets a record back, checking the file
against it (a key missing or unknown, a value of the wrong type) and failing in one line naming the file and the
key. So a file format is written down once, in its record, and the summaries, findings and the report read
attributes, not string keys.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, TypeVar

from pydantic import ConfigDict, TypeAdapter, ValidationError
from pydantic.dataclasses import dataclass as _pydantic_dataclass

from uqdrive.files import write_json
from uqdrive.schema import ConfigError, describe

RecordType = TypeVar("RecordType")
_RECORD = ConfigDict(extra="forbid")  # NaN is a value (a mean over no frames; null in a file)
_OPEN_RECORD = ConfigDict(extra="allow")  # method-specific keys beside the declared ones


def record(cls: type[RecordType] | None = None, *, open_keys: bool = False):
    """A result file's record: frozen, every key declared (``open_keys``: others allowed and kept)."""

    def wrap(c: type[RecordType]) -> type[RecordType]:
        return _pydantic_dataclass(c, config=_OPEN_RECORD if open_keys else _RECORD, frozen=True)

    return wrap if cls is None else wrap(cls)


def write_record(path: str | Path, value: Any, sort_keys: bool = True) -> Path:
    """The one writer of every stage's metrics file; ``sort_keys=False``: the record's own order (what a reader
    meets first, e.g. `dvc exp show`'s columns)."""
    write_json(path, as_dict(value), sort_keys=sort_keys)
    return Path(path)


def as_dict(value: Any) -> dict:
    """A record as plain JSON-able data, the keys an open record kept included."""
    return {**dataclasses.asdict(value), **extra_keys(value)}


def extra_keys(value: Any) -> dict:
    """The keys an open record holds beside its declared fields (pydantic keeps them in the instance's dict)."""
    declared = {f.name for f in dataclasses.fields(value)}
    return {k: v for k, v in vars(value).items() if k not in declared and not k.startswith("__")}


def read_record(cls: type[RecordType], path: str | Path, stage: str) -> RecordType:
    """The record in ``path``; a missing file names the ``stage`` that writes it, a stale one the key."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing; run the stage that writes it first: dvc repro {stage}")
    data, adapter = json.loads(path.read_text()), TypeAdapter(cls)
    while True:
        try:
            return adapter.validate_python(data)
        except ValidationError as err:
            if not _nan_for_null(data, err.errors()):
                raise ConfigError(f"{path}: {describe(err.errors()[0], cls)}; rerun dvc repro {stage}") from None


def _nan_for_null(data: Any, errors: list[dict]) -> bool:
    """Put NaN back where a float field holds null (`write_json` writes NaN so); False if any error is another."""
    if not all(e["type"] == "float_type" and e["input"] is None for e in errors):
        return False
    try:
        for e in errors:
            *parents, key = e["loc"]
            target = data
            for part in parents:
                target = target[part]
            target[key] = math.nan
    except (KeyError, IndexError, TypeError):
        return False
    return True
