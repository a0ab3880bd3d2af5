"""Hydra/OmegaConf glue: the `${params:KEY,ROOT}` resolver reads a knob from the project's params.yaml.

DVC cannot template a list into a command line, so stages that take the pipeline's lists
(e.g. which scenarios to preprocess) read them from params.yaml, the single source of truth;
a Hydra CLI override (`scenarios=[straight]`) still wins.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from omegaconf import OmegaConf


def read_param(key: str, root: str) -> object:
    path = Path(root) / "params.yaml"
    if not path.exists():
        raise FileNotFoundError(f"{path} not found: pass {key}=... on the command line or run from the project root")
    params = yaml.safe_load(path.read_text()) or {}
    if key not in params:
        raise KeyError(f"{path} has no key {key!r}; it has {sorted(params)}")
    return params[key]


def register_resolvers() -> None:
    if not OmegaConf.has_resolver("params"):
        OmegaConf.register_new_resolver("params", read_param)
