"""What a policy file may be, checked without importing what loads it (torch, ONNX Runtime, stable-baselines3): a
command refuses a missing file in a fraction of a second."""

from __future__ import annotations

from pathlib import Path

YAML = (".yaml", ".yml")
KINDS = "a TorchScript (.pt, .ts), ONNX (.onnx), stable-baselines3 (.zip) or policy YAML (.yaml) file"


def missing(path: str | Path) -> str | None:
    """The one line that refuses ``path`` when it is no file; None when it is one."""
    return None if Path(path).is_file() else f"{path}: no such file; expected {KINDS}"
