"""The one interface every Bayesian controller is used through: `Posterior.sample_probs(x, n)`.

A posterior is a deterministic trunk (run once per frame batch) plus a Bayesian head (run
for n weight draws at once, vectorised over a sample dimension). Callers that already hold
trunk outputs (e.g. a sweep over n) use `features` + `head_probs` and skip the trunk.

A method is one subclass: it names itself (`method`), declares the dataclass its
`conf/model/<method>.yaml` fills (`Settings`) and fits itself (`fit`). The yaml names the class
by Hydra's `_target_`, and model files record it, so the pipeline needs no list of methods.

Draws are only promised to be exact *per frame*: MCD and HMC share draw s across the frames
of a batch, VI draws its pre-activations per frame (local reparameterisation, same per-frame
distribution, ~100x fewer random numbers). No consumer may rely on draw s being the same
network for two frames.

Closed-loop controllers step many rollouts in lockstep and need each rollout's numbers to be its own:
`features_each` runs the trunk once for a batch of frames from different rollouts, and `head_probs_each` draws
every frame's head samples in one call, each frame from its own generator, with each frame's numbers bit for bit
those of the frame alone.
"""

from __future__ import annotations

import importlib
import re
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import torch
from torch import nn
from torch.nn.functional import unfold

from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import FrameSet
from uqdrive.models.pilotnet import INPUT_SHAPE, Architecture, Trunk
from uqdrive.schema import METHOD_NAME as METHOD_NAME_PATTERN
from uqdrive.schema import ConfigError, plain, validate

METHOD_NAME = re.compile(METHOD_NAME_PATTERN)


class FitData(Protocol):
    """What a method's `fit` reads: the train stage's `uqdrive.models.training.TrainingData`. Named here as a protocol
    because that record loads its base model through `uqdrive.models.checkpoint`, which builds posteriors from this
    module: the interface must not import it back."""

    train: FrameSet
    val: FrameSet
    bins: SteeringBins
    arch: Architecture
    eval_samples: int

    @property
    def base(self) -> Posterior: ...

    @property
    def train_features(self) -> torch.Tensor: ...

    @property
    def val_features(self) -> torch.Tensor: ...


@dataclass
class Fitted:
    """What `Posterior.fit` returns: the posterior, its learning curve (one dict per step, with at
    least step, train_loss, val_accuracy, val_nll) and method-specific metrics for metrics/train."""

    posterior: Posterior
    curve: list[dict]
    extra: dict[str, Any] = field(default_factory=dict)


class Posterior(nn.Module, ABC):
    """Trunk + Bayesian head over the steering classes of `bins`."""

    method: ClassVar[str]
    Settings: ClassVar[type]  # frozen dataclass of the method's conf/model keys (besides name and _target_)
    curve_unit: ClassVar[str] = "epoch"  # the x axis of its learning curve

    def __init__(self, arch: Architecture, bins: SteeringBins) -> None:
        super().__init__()
        self.arch = arch
        self.bins = bins
        self.trunk = Trunk(arch)

    @classmethod
    @abstractmethod
    def fit(cls, settings: Any, data: FitData, generator: torch.Generator, progress: bool = False) -> Fitted:
        """Fit the method on `data` (frames, or the base model's fixed trunk features)."""

    @classmethod
    def fit_replicates(
        cls,
        settings: Any,
        data: Sequence[FitData],
        generators: Sequence[torch.Generator],
        progress: bool = False,
    ) -> list[Fitted]:
        """Fit replicate r on ``data[r]`` with ``generators[r]``, each as `fit` alone would. Here one after the other;
        a method whose replicates train well as one batch (`uqdrive.models.stacking`) overrides it, and its `fit` is
        this with one replicate."""
        return [cls.fit(settings, d, g, progress) for d, g in zip(data, generators, strict=True)]

    @property
    def num_classes(self) -> int:
        return self.bins.num_classes

    def init_kwargs(self) -> dict:
        """Constructor arguments beyond (arch, bins) needed to rebuild this object from a checkpoint."""
        return {}

    @torch.no_grad()
    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Deterministic trunk: frames [B, 1, 48, 64] in [0, 1] → features [B, F]."""
        return self.trunk(x)

    @torch.no_grad()
    def features_each(self, x: torch.Tensor) -> torch.Tensor:
        """The trunk's features [B, F] of frames x [B, 1, 48, 64], each row bit for bit what the frame alone gives.

        `features` of a batch differs from the frames one at a time in the last bits (oneDNN and MKL pick
        kernels by batch size), so a rollout stepped in lockstep with others would not be the rollout run
        alone. Here the three strided 5x5 convolutions, ~90 % of the work, stay batched (oneDNN computes each
        frame of them alike at any batch size: `tests/test_models_lockstep.py` checks it), and the two 3x3
        convolutions and the dense layer, whose batched kernels mix rows, are one same-shaped GEMM per frame
        (`bmm`). Equal to `features` within float rounding (~1e-6).
        """
        if x.shape[1:] != INPUT_SHAPE:
            raise ValueError(f"expected frames [B, {', '.join(map(str, INPUT_SHAPE))}], got {list(x.shape)}")
        h = x
        for layer in self.trunk.convs:
            if isinstance(layer, nn.Conv2d) and layer.stride == (1, 1):
                h = _conv_per_frame(h, layer)
            elif not isinstance(layer, nn.Flatten):
                h = layer(h)
        h = h.flatten(1).unsqueeze(1)  # [B, 1, F]
        fc = self.trunk.fc
        return torch.relu(torch.baddbmm(fc.bias.expand(len(h), 1, -1), h, fc.weight.T.expand(len(h), -1, -1))[:, 0])

    @abstractmethod
    def head_probs(self, features: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """Softmax class probabilities [n, B, C] for n posterior draws of the head."""

    @torch.no_grad()
    def head_probs_each(self, features: torch.Tensor, n: int, generators: Sequence[torch.Generator]) -> torch.Tensor:
        """Probabilities [K, n, C] (frame-major) of n head draws for each of K frames (features [K, F]), frame k's
        from ``generators[k]`` as `head_probs` of the frame alone draws them, each frame's bit for bit what it gets
        alone (K = 1). Here one `head_probs` call per frame; a method whose head is a few GEMMs overrides it with
        one same-shaped GEMM per frame (`bmm`, as `features_each`), so lockstep frames share each layer's call."""
        return torch.cat([self.head_probs(features[k : k + 1], n, g) for k, g in enumerate(generators)], 1).transpose(
            0, 1
        )

    @torch.no_grad()
    def sample_probs(self, x: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """Softmax class probabilities [n, B, C] of n posterior draws for frames x [B, 1, 48, 64]."""
        return self.head_probs(self.features(x), n, generator)


def _conv_per_frame(h: torch.Tensor, conv: nn.Conv2d) -> torch.Tensor:
    """``conv(h)`` as one GEMM of the same shape per frame (im2col, then `bmm` over the frames)."""
    frames, _, height, width = h.shape
    (kh, kw), (sh, sw), (ph, pw) = conv.kernel_size, conv.stride, conv.padding
    rows, cols = (height + 2 * ph - kh) // sh + 1, (width + 2 * pw - kw) // sw + 1
    patches = unfold(h, conv.kernel_size, padding=conv.padding, stride=conv.stride).transpose(1, 2)  # [B, L, CK]
    weight = conv.weight.reshape(conv.out_channels, -1).T  # [CK, O]
    out = torch.baddbmm(conv.bias.expand(frames, 1, -1), patches, weight.expand(frames, -1, -1))  # [B, L, O]
    return out.transpose(1, 2).reshape(frames, conv.out_channels, rows, cols)


def per_frame_linear(h: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """``h @ weight + bias`` for each frame's rows h [K, m, in] (weight [in, out]) as one GEMM of the same shape per
    frame: what ``h[k] @ weight + bias`` of the frame alone gives, bit for bit, whatever K (`head_probs_each`)."""
    return torch.bmm(h, weight.expand(len(h), *weight.shape)) + bias


def check_draws(n: int) -> int:
    if int(n) != n or n < 1:
        raise ValueError(f"number of posterior draws n={n!r} must be a positive integer")
    return int(n)


def is_method_name(name: object) -> bool:
    return isinstance(name, str) and METHOD_NAME.fullmatch(name) is not None


def check_method(name: object) -> str:
    """A method name as used in file names (models/<method>.pt) and `methods` lists."""
    if not is_method_name(name):
        raise ConfigError(
            f"model.name={name!r} is not a method name: lower-case letters, digits and _ "
            f"(the name of a conf/model/<name>.yaml)"
        )
    return name


def posterior_class(target: object) -> type[Posterior]:
    """The Posterior subclass a dotted path (`_target_` of conf/model/*.yaml, `target` of a model file) names."""
    module_name, _, class_name = str(target).rpartition(".")
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError, ValueError) as err:
        raise ConfigError(
            f"model._target_={target!r} cannot be imported ({err}); it must be the dotted path "
            f"of a Posterior subclass, e.g. uqdrive.models.vi.VIPosterior"
        ) from None
    if not (isinstance(cls, type) and issubclass(cls, Posterior)) or getattr(cls, "__abstractmethods__", None):
        raise ConfigError(f"model._target_={target!r} is not a concrete uqdrive.models.posterior.Posterior subclass")
    return cls


def posterior_from_config(model: Any) -> type[Posterior]:
    """The Posterior class a conf/model section (mapping with name and _target_) names, checked against its name."""
    method = check_method(model.get("name"))
    if "_target_" not in model:
        raise ConfigError(
            f"model._target_ is missing in conf/model/{method}.yaml: it must name the Posterior "
            f"class, e.g. uqdrive.models.vi.VIPosterior"
        )
    cls = posterior_class(model["_target_"])
    if cls.method != method:
        raise ConfigError(
            f"model.name={method!r} does not match model._target_ {cls.__qualname__}, whose method is {cls.method!r}"
        )
    return cls


def posterior_settings(model: Any) -> tuple[type[Posterior], Any]:
    """The Posterior class a conf/model section names and its settings (the keys besides name and _target_)."""
    cls = posterior_from_config(model)
    settings = {k: v for k, v in plain(model).items() if k not in ("name", "_target_")}
    return cls, validate(cls.Settings, settings, "model")


def class_path(cls: type[Posterior]) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"
