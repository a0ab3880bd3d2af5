"""Config value checks shared by the stages: a bad value fails at start-up, before any work, with a
message naming the key, the value and what is allowed.

`ConfigError` is that failure; `one_line_errors` turns it, in a stage's entry point, into one line on
stderr and exit code 2 (Hydra would print a traceback for any exception leaving the task function).
"""

from __future__ import annotations

import functools
import math
import sys
from collections.abc import Callable
from typing import TypeVar

R = TypeVar("R")


class ConfigError(ValueError):
    """A bad config value; the message names the key, the value and what is allowed."""


def one_line_errors(main: Callable[..., R]) -> Callable[..., R]:
    """Wrap a stage's Hydra task function: a `ConfigError` prints ``error: <message>`` and exits with 2.

    Put it under ``@hydra.main`` (Hydra unwraps it to find the stage's config path). Checks run before
    any output is opened, so a run that stops here has written nothing.
    """

    @functools.wraps(main)
    def run(*args, **kwargs) -> R:
        try:
            return main(*args, **kwargs)
        except ConfigError as err:
            print(f"error: {err}", file=sys.stderr, flush=True)
            raise SystemExit(2) from None

    return run


def finite_number(key: str, value: object) -> float:
    """``value`` as a float if it is a finite real number (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{key}={value!r} must be a finite number")
    return float(value)


def integer(key: str, value: object, minimum: int) -> int:
    """``value`` if it is an integer (not a bool) ≥ ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{key}={value!r} must be an integer >= {minimum}")
    return value


def speed(key: str, value: object, max_speed: float) -> float:
    """A cruise speed in m/s within the car's limit (``vehicle.max_speed``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= max_speed:
        raise ConfigError(f"{key}={value!r} must be in (0, vehicle.max_speed={max_speed}] m/s")
    return float(value)


def seconds(key: str, value: object) -> float:
    """A duration (e.g. the horizon T) in seconds, > 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise ConfigError(f"{key}={value!r} must be a number of seconds > 0")
    return float(value)
