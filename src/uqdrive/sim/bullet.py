"""pybullet, quiet: the one place the project imports it and connects to it.

pybullet's C code writes straight to the process's file descriptors ("pybullet build time: …" on
stderr at import, "argv[0]=" on stdout at every connect), which Python-level redirection cannot
catch: it floods every log and, buffered by C stdio, lands in the middle of a subprocess's output.
Those two calls run with the descriptor pointed at /dev/null.
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TextIO

_LIBC = ctypes.CDLL(None) if os.name == "posix" else None


def _flush(stream: TextIO | None) -> None:
    """Flush Python's buffer and C stdio's, so nothing written before (or by pybullet) crosses the swap."""
    if stream is not None:
        stream.flush()
    if _LIBC is not None:
        _LIBC.fflush(None)


@contextmanager
def silenced(fd: int, stream: TextIO | None) -> Iterator[None]:
    """Point file descriptor ``fd`` (1 or 2; ``stream`` is Python's file on it) at /dev/null, then restore it."""
    _flush(stream)
    saved = os.dup(fd)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
        yield
    finally:
        _flush(None)
        os.dup2(saved, fd)
        os.close(saved)
        os.close(devnull)


with silenced(2, sys.stderr):
    import pybullet  # noqa: E402  (prints its build time on stderr)
from pybullet_utils.bullet_client import BulletClient  # noqa: E402


def connect_direct() -> BulletClient:
    """A DIRECT (headless) pybullet client, without its "argv[0]=" line on stdout."""
    with silenced(1, sys.stdout):
        return BulletClient(connection_mode=pybullet.DIRECT)
