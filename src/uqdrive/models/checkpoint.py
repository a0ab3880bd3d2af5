"""Model files `models/<method>.pt`: a posterior plus what is needed to trust it on load.

Each file carries a format tag and version, the method and its class, the class mapping (steering bins),
the input shape and the architecture, so that a consumer asking for a VI model with 21
classes gets exactly that or a clear error, never a silently wrong network.
"""

from __future__ import annotations

from pathlib import Path

import torch

from uqdrive.data.binning import SteeringBins
from uqdrive.files import atomic_path
from uqdrive.models.pilotnet import INPUT_SHAPE, Architecture
from uqdrive.models.posterior import Posterior, check_method, class_path, posterior_class

FORMAT = "uqdrive-posterior"
VERSION = 2  # 2: the file names its class (`target`), so any Posterior subclass loads without a list of methods


def save_posterior(posterior: Posterior, path: str | Path, metadata: dict | None = None) -> Path:
    """Write atomically: an interrupted save leaves the previous file (or none)."""
    path = Path(path)
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "method": posterior.method,
        "target": class_path(type(posterior)),
        "classes": posterior.bins.to_dict(),
        "input_shape": list(INPUT_SHAPE),
        "arch": posterior.arch.to_dict(),
        "init_kwargs": posterior.init_kwargs(),
        "state": posterior.state_dict(),
        "metadata": metadata or {},
    }
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def _reason(err: Exception) -> str:
    """What torch found, in its own first sentence, without the advice it appends for its own users (retrying with
    weights_only=False would run arbitrary code from the file)."""
    text = str(err).strip()
    first = text.splitlines()[0].split(". ")[0].rstrip(".") if text else ""
    return f"{type(err).__name__}: {first}" if first else type(err).__name__


def read_checkpoint(path: str | Path) -> dict:
    """The raw payload after checking it is a uqdrive model file of this version."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist; train it first (dvc repro train)")
    if path.stat().st_size == 0:
        raise ValueError(f"{path} is empty (0 bytes): not a uqdrive model file")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any bytes may reach here; whatever torch trips on, the file is not ours
        raise ValueError(f"{path} is not a uqdrive model file (torch cannot read it: {_reason(err)})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"{path} is not a uqdrive model file (no '{FORMAT}' format tag)")
    if payload.get("version") != VERSION:
        raise ValueError(
            f"{path} has model format version {payload.get('version')}, this code reads {VERSION}; retrain it"
        )
    return payload


def load_posterior(
    path: str | Path, expected_method: str | None = None, expected_classes: int | SteeringBins | None = None
) -> Posterior:
    """Rebuild a saved posterior (eval mode), failing clearly on another method or class mapping."""
    payload = read_checkpoint(path)
    method = payload["method"]
    if expected_method is not None and method != check_method(expected_method):
        raise ValueError(f"{path} holds a {method!r} model, expected {expected_method!r}")
    bins = SteeringBins.from_dict(payload["classes"])
    if isinstance(expected_classes, SteeringBins) and expected_classes != bins:
        raise ValueError(
            f"{path} was trained on classes {bins.to_dict()}, expected {expected_classes.to_dict()}; "
            f"retrain it with the current bins"
        )
    if isinstance(expected_classes, int) and expected_classes != bins.num_classes:
        raise ValueError(f"{path} predicts {bins.num_classes} classes, expected {expected_classes}")
    if tuple(payload["input_shape"]) != INPUT_SHAPE:
        raise ValueError(f"{path} takes input {payload['input_shape']}, this code feeds {list(INPUT_SHAPE)}")
    cls = posterior_class(payload["target"])
    if cls.method != method:
        raise ValueError(f"{path} holds a {method!r} model but names class {payload['target']} (method {cls.method!r})")
    posterior = cls(Architecture(**payload["arch"]), bins, **payload["init_kwargs"])
    posterior.load_state_dict(payload["state"])
    posterior.requires_grad_(False)
    return posterior.eval()
