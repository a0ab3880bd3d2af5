"""What every stage's Hydra entry point does around its work (`stage_main`)."""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import TypeVar

from uqdrive.checks import config_error
from uqdrive.resolvers import register_resolvers

R = TypeVar("R")


def stage_main(main: Callable[..., R]) -> Callable[..., R]:
    """Wrap a stage's Hydra task function; put it under ``@hydra.main`` (Hydra unwraps it to find the config).

    - Registers the config resolvers for each job: Hydra's joblib launcher hands every job in a worker
      process the launching process's resolver registry, which has none of ours.
    - A bad config value (a `ConfigError`, also one a resolver raised) prints ``error: <message>`` on
      stderr and exits with 2: one line, no traceback (Hydra prints one for any exception leaving the
      task function). Checks run before any output is opened, so such a run has written nothing.
    """

    @functools.wraps(main)
    def run(*args, **kwargs) -> R:
        register_resolvers()
        try:
            return main(*args, **kwargs)
        except Exception as err:
            cause = config_error(err)
            if cause is None:
                raise
            print(f"error: {cause}", file=sys.stderr, flush=True)
            raise SystemExit(2) from None

    return run
