"""A user's policy by config: a policy YAML (a class of the user's package by ``_target_``, or a network file) or a
network file itself (``.pt``/``.ts``: TorchScript, ``.onnx``: ONNX, ``.zip``: a stable-baselines3 agent,
`uqdrive.policy.sb3_policy`), as a picklable `UserPolicySpec` that every
worker builds its policy from. Which loader makes the policy is looked up by what the file is (`LOADERS`).

The policy YAML::

    policy:                     # a class implementing uqdrive.policy.interface.Policy, by Hydra's
      _target_: mypkg.LaneKeeper  # instantiate, with its settings as keyword arguments
      gain: 3.0
    # or, in place of `policy`, a network file (relative to this YAML):
    file: steer.pt              # TorchScript (.pt, .ts), ONNX (.onnx) or a stable-baselines3 agent (.zip)
    output: auto                # logits | steering | auto (by the output's width)
    input: gray                 # gray: [B, 1, 48, 64] as uqdrive's networks see it; rgb: [B, 3, H, W] as rendered
    mc_draws: 0                 # > 0: dropout on, 2·n passes per frame (TorchScript)
    speed: 6.0                  # m/s of an action that gives none
    eps: 0.1                    # η2's ball (steering units)
    bins: {low: -1.0, high: 1.0}  # the steering classes of logits and probability draws
    warnings:                   # optional: the paper's warning system on the policy's draws (uqdrive.policy.warnings)
      delta1: 0.7               #   η̂2 < δ1: warning 1; η̂2 < δ2: warning 2; MI > τ: warning 0
      delta2: 0.6
      tau: 0.45
      actions: {warning2: {speed: 0.0, alert: true, handover: true}}

A policy's identity (in a cell's key) is its file's bytes, or its class's package source and the bytes of the files
its settings name, with its settings; not where the file lies. Editing any of them makes a new cell.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import inspect
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import yaml
from pydantic import Field

from uqdrive.data.binning import SteeringBins
from uqdrive.deps import file_digest, source_digest
from uqdrive.policy.interface import Policy
from uqdrive.policy.policy_path import KINDS, YAML, missing
from uqdrive.policy.sb3_policy import SB3Policy, load_sb3
from uqdrive.policy.slots import PolicyFailure, PolicySlots, UserWarnings
from uqdrive.policy.tensor_policies import (
    FrameInput,
    OnnxPolicy,
    Output,
    TorchScriptPolicy,
    first_line,
    load_onnx,
    load_torchscript,
)
from uqdrive.policy.warnings import WarningConfig
from uqdrive.schema import ConfigError, Positive, Str, schema, validate


@schema(frozen=True)
class PolicyConfig:
    """A policy YAML's keys (see the module); exactly one of ``policy`` and ``file``."""

    policy: dict[str, Any] | None = None
    file: Str | None = None
    output: Output = "auto"
    input: FrameInput = "gray"
    mc_draws: Annotated[int, Field(ge=0, strict=True)] = 0
    speed: Positive = 6.0
    eps: Positive = 0.1
    bins: SteeringBins = dataclasses.field(default_factory=SteeringBins)
    warnings: WarningConfig | None = None

    def __post_init__(self) -> None:
        if (self.policy is None) == (self.file is None):
            raise ValueError("policy: give exactly one of `policy` (a class by _target_) and `file` (a network)")
        if self.policy is not None and not isinstance(self.policy.get("_target_"), str):
            raise ValueError(f"policy={self.policy!r} needs `_target_: package.module.Class`")


@dataclasses.dataclass(frozen=True)
class UserPolicySpec:
    """A picklable recipe of a user's policy (`build` in each worker). ``kind``: what it is, a key of `LOADERS`;
    ``target``: the class's ``_target_`` mapping as JSON (a class); ``path``: the network file (not identity: its
    bytes are, as ``digest``); ``name``: what its errors call it."""

    NOT_IDENTITY = ("path", "name", "search_path")

    kind: str
    digest: str
    name: str
    path: str = ""
    target: str = ""
    speed: float = 6.0
    eps: float = 0.1
    bins: SteeringBins = dataclasses.field(default_factory=SteeringBins)
    output: str = "auto"
    frame_input: str = "gray"
    mc_draws: int = 0
    search_path: str = ""  # a class's YAML's folder: its package may lie beside it, uninstalled
    warnings: WarningConfig | None = None
    native: bool = False  # over the env's own spaces (`uqdrive.policy.native`), not uqdrive's frame → steer

    def build(self, control_hz: float) -> PolicySlots | Any:
        """The policy, one instance per lockstep slot, made by the loader of its kind (`LOADERS`); a native agent's
        by its kind's native loader."""
        if self.native:
            from uqdrive.policy.native import NativeSlots

            return NativeSlots(self.name, LOADERS[self.kind].native(self), self.eps, self.warnings)
        centres = np.asarray(self.bins.centres)
        make = LOADERS[self.kind].factory(self, centres)
        warnings = UserWarnings(self.warnings, control_hz) if self.warnings is not None else None
        return PolicySlots(self.name, make, centres, self.eps, self.speed, warnings)


LoaderFactory = Callable[[UserPolicySpec, np.ndarray], Callable[[], Policy]]
"""A kind's loader: a spec and its steering classes → what makes an instance per slot."""


@dataclasses.dataclass(frozen=True)
class Loader:
    """How one kind of policy becomes instances: ``factory(spec, centres)`` makes them; ``suffixes``: the network
    files of this kind (none: a class by its YAML); ``draws``: whether ``mc_draws`` applies (a stable-baselines3
    agent acts deterministically); ``native(spec)``: what makes an instance of an agent over the env's own spaces
    (`uqdrive.policy.native`)."""

    factory: LoaderFactory
    native: Callable[[UserPolicySpec], Callable[[], Any]]
    suffixes: tuple[str, ...] = ()
    draws: bool = True


def _class_loader(spec: UserPolicySpec, centres: np.ndarray) -> Callable[[], Policy]:
    _search(spec.search_path)
    return _class_factory(spec.name, json.loads(spec.target))


def _network_loader(network: type[TorchScriptPolicy | OnnxPolicy]) -> LoaderFactory:
    def factory(spec: UserPolicySpec, centres: np.ndarray) -> Callable[[], Policy]:
        return network.loader(spec.path, centres, spec.output, spec.frame_input, spec.mc_draws)

    return factory


def _native_class(spec: UserPolicySpec) -> Callable[[], Any]:
    """A class by ``_target_`` made per slot, or a function by ``_target_`` (its other keys bound as settings)."""
    _search(spec.search_path)
    target = json.loads(spec.target)
    found = _resolve(target["_target_"])
    if inspect.isclass(found):
        return _class_factory(spec.name, target)
    from uqdrive.policy.native import FunctionAgent

    settings = {k: v for k, v in target.items() if k != "_target_"}
    return lambda: FunctionAgent(found, settings)


def _native_torchscript(spec: UserPolicySpec) -> Callable[[], Any]:
    import torch

    from uqdrive.policy.native import TensorAgent

    module = load_torchscript(spec.path)
    module.eval()

    def run(x: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return module(torch.from_numpy(x)).numpy()

    return lambda: TensorAgent(spec.name, run)


def _native_onnx(spec: UserPolicySpec) -> Callable[[], Any]:
    from uqdrive.policy.native import TensorAgent

    session = load_onnx(spec.path)
    name = session.get_inputs()[0].name
    return lambda: TensorAgent(spec.name, lambda x: session.run(None, {name: x})[0])


def _native_sb3(spec: UserPolicySpec) -> Callable[[], Any]:
    from uqdrive.policy.native import PredictAgent

    policy = load_sb3(spec.path)
    return lambda: PredictAgent(policy)


LOADERS: dict[str, Loader] = {
    "class": Loader(_class_loader, _native_class),
    "torchscript": Loader(_network_loader(TorchScriptPolicy), _native_torchscript, (".pt", ".ts", ".pth", ".jit")),
    "onnx": Loader(_network_loader(OnnxPolicy), _native_onnx, (".onnx",)),
    "sb3": Loader(lambda spec, centres: SB3Policy.loader(spec.path, centres), _native_sb3, (".zip",), draws=False),
}
"""Each kind of policy a spec may be (its ``kind``, recorded with a certificate) and how it is loaded."""
NETWORK_KINDS = {suffix: kind for kind, loader in LOADERS.items() for suffix in loader.suffixes}
"""The kind of a network file, by its suffix."""


def _search(folder: str) -> None:
    """Let ``folder`` be searched for the class's package, after the installed ones (a worker process too)."""
    if folder and folder not in sys.path:
        sys.path.append(folder)


def _class_factory(name: str, target: dict[str, Any]):
    from hydra.utils import instantiate

    def make() -> Any:
        try:
            return instantiate(target)
        except Exception as err:  # Hydra wraps the class's own exception: its first line says which
            raise PolicyFailure(f"{name}: could not be made: {first_line(err)}") from None

    return make


def load_policy(source: str | Path, native: bool = False, **settings: Any) -> UserPolicySpec:
    """``source`` (a network file or a policy YAML) as a spec; ``native``: an agent over the env's own spaces (a
    ``_target_`` may then name a function too); ``settings``: keys a YAML would set (speed, eps, bins, …), under the
    YAML's own. Fails in one line naming the file: missing, of another kind, not a valid YAML."""
    spec = _load_policy(Path(source), native, settings)
    if native and spec.mc_draws:
        raise PolicyFailure(f"{source}: mc_draws={spec.mc_draws}: an agent over the env's own spaces gives its draws")
    return dataclasses.replace(spec, native=True) if native else spec


def _load_policy(path: Path, native: bool, settings: dict[str, Any]) -> UserPolicySpec:
    if (refusal := missing(path)) is not None:
        raise PolicyFailure(refusal)
    suffix = path.suffix.lower()
    if suffix in YAML:
        try:
            data = yaml.safe_load(path.read_text())
        except (yaml.YAMLError, UnicodeDecodeError) as err:
            raise PolicyFailure(f"{path}: expected a policy YAML, got {type(err).__name__}") from None
        if not isinstance(data, dict):
            raise PolicyFailure(f"{path}: expected a mapping of policy settings, got {type(data).__name__}")
        config = _validated(path, {**settings, **data})
        if config.file is not None:
            return _network_spec(path.parent / config.file, config)
        return _class_spec(config, path.parent.resolve(), native)
    if suffix in NETWORK_KINDS:
        return _network_spec(path, _validated(path, {**settings, "file": str(path)}))
    raise PolicyFailure(f"{path}: expected {KINDS}, got a {suffix or 'suffix-less'} file")


def _validated(path: Path, data: dict[str, Any]) -> PolicyConfig:
    try:
        return validate(PolicyConfig, data)
    except ConfigError as err:
        raise PolicyFailure(f"{path}: {err}") from None


def _network_spec(path: Path, config: PolicyConfig) -> UserPolicySpec:
    if (refusal := missing(path)) is not None:
        raise PolicyFailure(refusal)
    suffix = path.suffix.lower()
    if suffix not in NETWORK_KINDS:
        raise PolicyFailure(f"{path}: expected a TorchScript (.pt, .ts), ONNX (.onnx) or SB3 (.zip) file, got {suffix}")
    kind = NETWORK_KINDS[suffix]
    if not LOADERS[kind].draws and config.mc_draws:
        raise PolicyFailure(f"{path}: mc_draws={config.mc_draws}: a stable-baselines3 agent acts deterministically")
    settings = {"output": config.output, "frame_input": config.input, "mc_draws": config.mc_draws}
    return UserPolicySpec(kind, file_digest(path), str(path), path=str(path), **_common(config), **settings)


def _resolve(name: str) -> Any:
    module, _, attribute = name.rpartition(".")
    return getattr(importlib.import_module(module), attribute)


def _class_spec(config: PolicyConfig, folder: Path, native: bool = False) -> UserPolicySpec:
    """A class's spec (imported here, so a typo in ``_target_`` fails before any rollout; its package is looked for
    beside its YAML, ``folder``, too). Its identity: the source of the package its class is in, and the bytes of
    every file its settings name (weights it loads), so that editing either makes a new cell."""
    _search(str(folder))
    name = config.policy["_target_"]
    try:
        cls = _resolve(name)
        if not (inspect.isclass(cls) or native and inspect.isfunction(cls)):
            raise TypeError(f"{name} is a {type(cls).__name__}")
        digest = hashlib.sha256(source_digest(cls.__module__).encode())
    except Exception as err:  # ImportError, AttributeError, a class without a source file
        raise PolicyFailure(f"policy._target_={name}: expected an importable class, got {first_line(err)}") from None
    for path in sorted(_named_files(config.policy)):
        digest.update(f"{path}:{file_digest(path)}".encode())
    target = json.dumps(config.policy, sort_keys=True)
    return UserPolicySpec("class", digest.hexdigest(), name, target=target, search_path=str(folder), **_common(config))


def _named_files(value: Any) -> set[str]:
    """The existing files a class's settings name, anywhere in them."""
    if isinstance(value, dict):
        return {f for v in value.values() for f in _named_files(v)}
    if isinstance(value, list):
        return {f for v in value for f in _named_files(v)}
    return {value} if isinstance(value, str) and Path(value).is_file() else set()


def _common(config: PolicyConfig) -> dict[str, Any]:
    return {"speed": float(config.speed), "eps": float(config.eps), "bins": config.bins, "warnings": config.warnings}
