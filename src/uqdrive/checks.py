"""Config value checks shared by the stages: a bad value fails at start-up, before any work, with a
message naming the key, the value and what is allowed.

`ConfigError` is that failure; `uqdrive.stage.stage_main` turns it into one line on stderr and exit code 2.
"""

from __future__ import annotations

import math


class ConfigError(ValueError):
    """A bad config value; the message names the key, the value and what is allowed."""


def config_error(err: BaseException) -> ConfigError | None:
    """The `ConfigError` behind ``err``, if any (OmegaConf wraps one raised by a resolver)."""
    while err is not None and not isinstance(err, ConfigError):
        err = err.__cause__ or err.__context__
    return err


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
