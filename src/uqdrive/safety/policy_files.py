"""A user's policy by config: a policy YAML (a class of the user's package by ``_target_``, or a network file) or a
network file itself (``.pt``/``.ts``: TorchScript, ``.onnx``: ONNX, ``.zip``: a stable-baselines3 agent,
`uqdrive.policy.sb3_policy`), as a picklable `UserPolicySpec` that every
worker builds its policy from.

The policy YAML::

    policy:                     # a class implementing uqdrive.policy.user_policy.DrivingPolicy, by Hydra's
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
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import Field

from uqdrive.data.binning import SteeringBins
from uqdrive.deps import source_digest
from uqdrive.policy.controller import Command
from uqdrive.policy.sb3_policy import SB3Policy
from uqdrive.policy.tensor_policies import FrameInput, OnnxPolicy, Output, TorchScriptPolicy, first_line
from uqdrive.policy.user_policy import PolicyFailure, UserPolicies, UserWarnings
from uqdrive.policy.warnings import WarningConfig
from uqdrive.safety.cells import file_digest
from uqdrive.schema import ConfigError, Positive, Str, schema, validate

TORCHSCRIPT = (".pt", ".ts", ".pth", ".jit")
ONNX = (".onnx",)
SB3 = (".zip",)
NETWORKS = TORCHSCRIPT + ONNX + SB3
YAML = (".yaml", ".yml")
KINDS = "a TorchScript (.pt, .ts), ONNX (.onnx), stable-baselines3 (.zip) or policy YAML (.yaml) file"


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
    """A picklable recipe of a user's policy (`build` in each worker). ``kind``: class, torchscript or onnx;
    ``target``: the class's ``_target_`` mapping as JSON (a class); ``path``: the network file (not identity: its
    bytes are, as ``digest``); ``name``: what its errors call it."""

    NOT_IDENTITY = ("path", "name", "search_path")

    kind: Literal["class", "torchscript", "onnx", "sb3"]
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

    def build(self, control_hz: float) -> UserPolicies:
        """The rollout engine's policy: one instance per slot."""
        centres = np.asarray(self.bins.centres)
        if self.kind == "class":
            _search(self.search_path)
            make = _class_factory(self.name, json.loads(self.target))
        elif self.kind == "sb3":
            make = SB3Policy.loader(self.path, centres)
        else:
            network = TorchScriptPolicy if self.kind == "torchscript" else OnnxPolicy
            make = network.loader(self.path, centres, self.output, self.frame_input, self.mc_draws)
        warnings = UserWarnings(self.warnings, control_hz) if self.warnings is not None else None
        return UserPolicies(self.name, make, centres, self.eps, self.speed, warnings)


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


def load_policy(source: str | Path, **settings: Any) -> UserPolicySpec:
    """``source`` (a network file or a policy YAML) as a spec; ``settings``: keys a YAML would set (speed, eps, bins,
    …), under the YAML's own. Fails in one line naming the file: missing, of another kind, not a valid YAML."""
    path = Path(source)
    if not path.is_file():
        raise PolicyFailure(f"{path}: no such file; expected {KINDS}")
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
        return _class_spec(config, path.parent.resolve())
    if suffix in NETWORKS:
        return _network_spec(path, _validated(path, {**settings, "file": str(path)}))
    raise PolicyFailure(f"{path}: expected {KINDS}, got a {suffix or 'suffix-less'} file")


def _validated(path: Path, data: dict[str, Any]) -> PolicyConfig:
    try:
        return validate(PolicyConfig, data)
    except ConfigError as err:
        raise PolicyFailure(f"{path}: {err}") from None


def _network_spec(path: Path, config: PolicyConfig) -> UserPolicySpec:
    if not path.is_file():
        raise PolicyFailure(f"{path}: no such file; expected {KINDS}")
    suffix = path.suffix.lower()
    if suffix not in NETWORKS:
        raise PolicyFailure(f"{path}: expected a TorchScript (.pt, .ts), ONNX (.onnx) or SB3 (.zip) file, got {suffix}")
    kind = "onnx" if suffix in ONNX else "sb3" if suffix in SB3 else "torchscript"
    if kind == "sb3" and config.mc_draws:
        raise PolicyFailure(f"{path}: mc_draws={config.mc_draws}: a stable-baselines3 agent acts deterministically")
    settings = {"output": config.output, "frame_input": config.input, "mc_draws": config.mc_draws}
    return UserPolicySpec(kind, file_digest(path), str(path), path=str(path), **_common(config), **settings)


def _class_spec(config: PolicyConfig, folder: Path) -> UserPolicySpec:
    """A class's spec (imported here, so a typo in ``_target_`` fails before any rollout; its package is looked for
    beside its YAML, ``folder``, too). Its identity: the source of the package its class is in, and the bytes of
    every file its settings name (weights it loads), so that editing either makes a new cell."""
    _search(str(folder))
    name = config.policy["_target_"]
    module, _, attribute = name.rpartition(".")
    try:
        cls = getattr(importlib.import_module(module), attribute)
        if not inspect.isclass(cls):
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


def probe_policy(job: Any) -> Command:
    """Build the job's policy here and decide rollout 0's first frame in the job's own kind of world, so that a
    policy that cannot be made or answers in the wrong shape or range fails in one line before any rollout; the
    frame's command (what it gives: its draws, for one)."""
    from uqdrive.safety.executors import WorkerEnvs

    policy = job.policy.build(job.control_hz)
    where, envs = job.condition(0), WorkerEnvs(job, 1)
    try:
        (env,) = envs.first(1)
        frame = env.reset(job.base_seed, where.scenario, where.weather, where.noise, render=policy.needs_camera)
        policy.reset(env, job.base_seed, 0)
        (command,) = policy.act_batch([0], [frame], [env.last_info])
        return command
    finally:
        envs.close()  # the env is left to the next job of this process (an in-process worker's)
