"""Typed records: what one stage writes and another reads (a safety cell, an avoid result, a trained controller's
metrics, the findings, the report's headline), each a frozen dataclass declared beside the code that computes it.

`write_record` is the one writer of every stage's metrics file; `read_record` gets a record back, checking the file
against it (a key missing or unknown, a value of the wrong type) and failing in one line naming the file and the
key. So a file format is written down once, in its record, and the summaries, findings and the report read
attributes, not string keys.

A record that carries a result computed elsewhere (a decided finding, a decided claim) embeds it in a `flattened`
field rather than repeating its fields: the file keeps the result's keys beside the record's own, one flat object,
and `read_record` gathers them back into the embedded result.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path
from typing import Any, TypeVar

from pydantic import ConfigDict, TypeAdapter, ValidationError, model_validator
from pydantic.dataclasses import dataclass as _pydantic_dataclass

from uqdrive.files import write_json
from uqdrive.schema import ConfigError, describe

RecordType = TypeVar("RecordType")
_RECORD = ConfigDict(extra="forbid")  # NaN is a value (a mean over no frames; null in a file)
_OPEN_RECORD = ConfigDict(extra="allow")  # method-specific keys beside the declared ones
_FLATTEN = "flatten"  # metadata: the embedded result's file keys, by field name (its own name where not renamed)
_LEFT = "left"  # metadata: the embedded result's fields its file does not hold (each at its default)


def record(cls: type[RecordType] | None = None, *, open_keys: bool = False):
    """A result file's record: frozen, every key declared (``open_keys``: others allowed and kept)."""

    def wrap(c: type[RecordType]) -> type[RecordType]:
        if any(isinstance(v, dataclasses.Field) and _FLATTEN in v.metadata for v in vars(c).values()):
            c._gather_flattened = model_validator(mode="before")(classmethod(_gather_flattened))  # type: ignore[attr-defined]
        return _pydantic_dataclass(c, config=_OPEN_RECORD if open_keys else _RECORD, frozen=True)

    return wrap if cls is None else wrap(cls)


def flattened(keys: dict[str, str] | None = None, left: tuple[str, ...] = ()) -> Any:
    """A record field holding an embedded result (a dataclass) whose keys the file holds beside the record's own;
    ``keys``: a field's key in the file where it is not the field's name (a cell's `Estimate.value` as ``eta1``),
    ``left``: fields the file does not hold, each at its default (written only while it holds that default)."""
    return dataclasses.field(metadata={_FLATTEN: dict(keys or {}), _LEFT: tuple(left)})


def _file_keys(embedded: type, meta: Any) -> dict[str, str]:
    """An embedded result's fields → their keys in the file, those ``left`` out left out."""
    renamed, left = meta[_FLATTEN], meta[_LEFT]
    return {g.name: renamed.get(g.name, g.name) for g in dataclasses.fields(embedded) if g.name not in left}


def _gather_flattened(cls: type, data: Any) -> Any:
    """A file's flat object with each `flattened` field's keys moved under the field's name, in place: so an error
    names the key where `read_record`'s NaN repair finds it."""
    if isinstance(data, dict):
        for f in dataclasses.fields(cls):
            if _FLATTEN in f.metadata and f.name not in data:
                embedded = cls.__pydantic_fields__[f.name].annotation  # type: ignore[attr-defined]
                keys = _file_keys(embedded, f.metadata).items()
                data[f.name] = {name: data.pop(key) for name, key in keys if key in data}
    return data


def write_record(path: str | Path, value: Any, sort_keys: bool = True) -> Path:
    """The one writer of every stage's metrics file; ``sort_keys=False``: the record's own order (what a reader
    meets first, e.g. `dvc exp show`'s columns)."""
    write_json(path, as_dict(value), sort_keys=sort_keys)
    return Path(path)


def as_dict(value: Any) -> dict:
    """A record as plain JSON-able data, the keys an open record kept included."""
    return {**_plain(value), **extra_keys(value)}


def _plain(value: Any) -> Any:
    """`dataclasses.asdict`, with each `flattened` field's keys spread among its record's own."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out: dict = {}
        for f in dataclasses.fields(value):
            if _FLATTEN not in f.metadata:
                out[f.name] = _plain(getattr(value, f.name))
            else:
                out.update(_spread(value, f))
        return out
    if isinstance(value, (list, tuple)):
        return type(value)(_plain(v) for v in value)
    if isinstance(value, dict):
        return {_plain(k): _plain(v) for k, v in value.items()}
    return copy.deepcopy(value)


def _spread(value: Any, f: dataclasses.Field) -> dict:
    """A `flattened` field's keys as its record's file holds them (renamed, those left out at their default)."""
    inner = getattr(value, f.name)
    for g in dataclasses.fields(inner):
        if g.name in f.metadata[_LEFT] and getattr(inner, g.name) != g.default:
            kept = getattr(inner, g.name)
            raise ValueError(f"{type(value).__name__}.{f.name}.{g.name} is not kept in its file: {kept!r}")
    spread = {key: _plain(getattr(inner, name)) for name, key in _file_keys(type(inner), f.metadata).items()}
    if clash := set(spread) & {g.name for g in dataclasses.fields(value)}:
        raise ValueError(f"{type(value).__name__}.{f.name} repeats the record's keys {sorted(clash)}")
    return spread


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
