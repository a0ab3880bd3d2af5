"""What driving a Gymnasium env as it is needs beside `uqdrive.sim.gym_world.GymWorld` (``hooks: native``, or the
env's own safety signals in any world): an agent's action as the env's action space holds it (`in_space`) and the
user's predicate a path is judged by (`predicate`, ``gym_world.safe_when``)."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

import numpy as np

from uqdrive.schema import ConfigError


def predicate(name: str) -> Callable[[Any, dict[str, Any]], Any] | None:
    """The function ``module:function`` names (None for ""), or one line naming ``gym_world.safe_when``."""
    if not name:
        return None
    module, _, attr = name.partition(":")
    try:
        found = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as err:
        raise ConfigError(f"gym_world.safe_when={name!r}: {type(err).__name__}: {err}") from None
    if not callable(found):
        raise ConfigError(f"gym_world.safe_when={name!r}: expected a function (obs, info) -> bool")
    return found


def in_space(action: Any, space: Any) -> Any:
    """``action`` as ``space`` holds it (an integer of a Discrete, an array of the space's dtype for a Box or
    MultiDiscrete), or None where it is not in the space."""
    try:
        if hasattr(space, "n") and not hasattr(space, "nvec"):  # Discrete
            value = np.asarray(action)
            if value.size != 1 or not np.issubdtype(value.dtype, np.integer) and value.reshape(-1)[0] % 1:
                return None
            action = int(value.reshape(-1)[0])
        elif getattr(space, "shape", None) is not None and getattr(space, "dtype", None) is not None:
            value = np.asarray(action)
            if value.shape != space.shape and value.size == int(np.prod(space.shape)):
                value = value.reshape(space.shape)
            if np.issubdtype(space.dtype, np.integer) and not np.all(np.mod(value, 1) == 0):
                return None
            action = value.astype(space.dtype)
        return action if space.contains(action) else None
    except (TypeError, ValueError):
        return None


def short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."
