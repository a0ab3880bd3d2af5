"""The one config validator: the settings dataclasses are the schema, checked once at a stage's boundary.

A schema is a `pydantic` dataclass (`@schema`): its field types, defaults and bounds (`Field(gt=0)`)
say everything a config key may hold; cross-field rules live in its ``__post_init__`` and raise
`invalid(...)`. `validate` builds a schema from a config section and turns the first thing wrong
(a typo'd key, a wrong type, a value out of range) into one `ConfigError` line naming the full key
path; `uqdrive.stage` prints that line and exits with 2 before the stage does any work.

The defaults are written once, in the dataclasses: the module owning a config group's schema stores its
defaults (`defaults`) in Hydra's ConfigStore as `<group>_schema` (`uqdrive.sim.config.register_schemas`, …;
each stage script registers the groups it composes), and the group's yaml files list only what differs
(``defaults: [/<group>_schema@_here_, _self_]``), so ``scenario.ring_radius=20`` overrides a key no yaml spells out.
"""

from __future__ import annotations

import dataclasses
import difflib
import typing
from collections.abc import Mapping
from typing import Annotated, Any, TypeVar

from pydantic import ConfigDict, Field, Strict, TypeAdapter, ValidationError
from pydantic.dataclasses import dataclass as _pydantic_dataclass

SchemaType = TypeVar("SchemaType")

# Scalars as a config means them: no silent casts ("3" is not a number, true is not 1, 1.5 is not an int).
Float = Annotated[float, Strict()]
Int = Annotated[int, Strict()]
Bool = Annotated[bool, Strict()]
Str = Annotated[str, Strict(), Field(min_length=1)]
Unit = Annotated[float, Strict(), Field(ge=0, le=1)]  # a fraction or probability in [0, 1]
OpenUnit = Annotated[float, Strict(), Field(gt=0, lt=1)]  # (0, 1): θ, γ
Positive = Annotated[float, Strict(), Field(gt=0)]
NonNegative = Annotated[float, Strict(), Field(ge=0)]
Count = Annotated[int, Strict(), Field(ge=1)]
Seed = Annotated[int, Strict(), Field(ge=0)]
Color = tuple[Unit, Unit, Unit]  # RGB in [0, 1]
METHOD_NAME = r"[a-z][a-z0-9_]*"  # a posterior method's name: conf/model/<name>.yaml, models/<name>.pt
MethodName = Annotated[str, Strict(), Field(pattern=f"^{METHOD_NAME}$")]

_SECTION = ConfigDict(extra="forbid", allow_inf_nan=False)
_ROOT = ConfigDict(extra="ignore", allow_inf_nan=False)


class ConfigError(ValueError):
    """A bad config value; the message names the full key path, the value and what is allowed."""


def schema(cls: type[SchemaType] | None = None, *, root: bool = False, frozen: bool = False, kw_only: bool = False):
    """A config section's schema: unknown keys are errors. ``root=True`` for a stage's whole config, whose
    top level also holds keys of other stages (the profile sets them all) and so ignores what it does not name.
    ``kw_only``: fields without defaults may follow an inherited schema's fields with defaults (root: always)."""

    def wrap(c: type[SchemaType]) -> type[SchemaType]:
        config = _ROOT if root else _SECTION
        return _pydantic_dataclass(c, config=config, frozen=frozen, kw_only=root or kw_only)

    return wrap if cls is None else wrap(cls)


def invalid(key: str, value: object, must: str) -> ValueError:
    """A cross-field rule's failure, raised from a schema's ``__post_init__``: ``key`` relative to the schema
    (`validate` prefixes the section's path)."""
    return ValueError(f"{key}={value!r} {must}")


def config_error(err: BaseException | None) -> ConfigError | None:
    """The `ConfigError` behind ``err``, if any (OmegaConf wraps one raised by a resolver)."""
    while err is not None and not isinstance(err, ConfigError):
        err = err.__cause__ or err.__context__
    return err


def plain(value: Any) -> Any:
    """OmegaConf containers -> plain Python, resolved."""
    from omegaconf import DictConfig, ListConfig, OmegaConf

    if isinstance(value, (DictConfig, ListConfig)):
        return OmegaConf.to_container(value, resolve=True)
    return value


def validate(cls: type[SchemaType], data: Any, path: str = "") -> SchemaType:
    """``data`` (a dict or DictConfig) as a ``cls``, or one `ConfigError` line naming the full key path."""
    try:
        return TypeAdapter(cls).validate_python(plain(data))
    except ValidationError as err:
        raise ConfigError(describe(err.errors()[0], cls, path)) from None


def describe(error: Mapping[str, Any], cls: type, path: str = "") -> str:
    """One pydantic error as ``<full.key>=<value> <what is wrong>``."""
    key = _dotted(path, error["loc"])
    if error["type"] == "value_error":  # a cross-field rule: its message starts with the key inside the section
        return f"{key}.{error['ctx']['error']}" if key else str(error["ctx"]["error"])
    if error["type"] in ("unexpected_keyword_argument", "extra_forbidden"):
        known = _field_names(cls, error["loc"][:-1])
        close = difflib.get_close_matches(str(error["loc"][-1]), known, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        return f"{key}: unknown key; {hint}known keys: {', '.join(known)}"
    if error["type"] == "missing" or error["type"] == "missing_argument":
        return f"{key} is required"
    message = error["msg"][0].lower() + error["msg"][1:]
    shape = _shape(_type_at(cls, error["loc"]))
    expected = f"; expected {shape}" if shape.startswith(("[", "{")) else ""
    return f"{key}={error['input']!r}: {message}{expected}"


def _type_at(cls: Any, loc: tuple) -> Any:
    """The schema's type at ``loc`` (field names and list indices), None where it cannot be followed."""
    tp = cls
    for part in loc:
        inner = _unwrap(tp)
        if isinstance(part, str) and dataclasses.is_dataclass(inner):
            tp = typing.get_type_hints(inner, include_extras=True).get(part)
        elif isinstance(part, int):
            args = [a for a in typing.get_args(_bare(tp)) if a is not Ellipsis]
            tp = args[min(part, len(args) - 1)] if args else None
        else:
            return None
    return tp


def _bare(tp: Any) -> Any:
    while typing.get_origin(tp) is Annotated:
        tp = typing.get_args(tp)[0]
    return tp


def _shape(tp: Any, depth: int = 0) -> str:
    """What a structured key looks like in a config, e.g. ``[{key: …, range: […, …]}, …]``."""
    tp = _bare(tp)
    if depth > 3 or tp is None:
        return "…"
    if dataclasses.is_dataclass(tp):
        hints = typing.get_type_hints(tp, include_extras=True)
        return "{" + ", ".join(f"{name}: {_shape(hint, depth + 1)}" for name, hint in hints.items()) + "}"
    origin, args = typing.get_origin(tp), [a for a in typing.get_args(tp) if a is not Ellipsis]
    if origin in (tuple, list) and args:
        if Ellipsis in typing.get_args(tp) or origin is list:
            return f"[{_shape(args[0], depth + 1)}, …]"
        return "[" + ", ".join(_shape(a, depth + 1) for a in args) + "]"
    if origin is dict:
        return "{…: …}"
    return "…"


def _dotted(path: str, loc: tuple) -> str:
    key = path
    for part in loc:
        key += f"[{part}]" if isinstance(part, int) else (f".{part}" if key else str(part))
    return key


def _field_names(cls: Any, loc: tuple) -> list[str]:
    """Keys the schema allows at ``loc`` inside ``cls`` (for an unknown key's hint)."""
    for part in loc:
        if isinstance(part, int) or typing.get_origin(_bare(cls)) is dict:  # an item of a list or mapping: its type
            args = [a for a in typing.get_args(_bare(cls)) if a is not Ellipsis]
            cls = args[-1] if args else None
            continue
        cls = _unwrap(cls)
        cls = typing.get_type_hints(cls, include_extras=True).get(part) if dataclasses.is_dataclass(cls) else None
    cls = _unwrap(cls)
    return [f.name for f in dataclasses.fields(cls)] if dataclasses.is_dataclass(cls) else []


def _unwrap(tp: Any) -> Any:
    """The dataclass inside ``Annotated[...]`` / ``X | None``, if any."""
    while typing.get_origin(tp) is Annotated:
        tp = typing.get_args(tp)[0]
    candidates = [a for a in typing.get_args(tp) if dataclasses.is_dataclass(a)]
    return candidates[0] if candidates and not dataclasses.is_dataclass(tp) else tp


def defaults(cls: type) -> dict[str, Any]:
    """A schema's defaults as a plain dict (fields without one left out): the ConfigStore node its config
    group's yaml files extend."""
    fields = cls.__pydantic_fields__
    return {
        name: _plain_default(info.get_default(call_default_factory=True))
        for name, info in fields.items()
        if not info.is_required()
    }


def _plain_default(value: Any) -> Any:
    return dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value
