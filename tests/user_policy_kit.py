"""A user's package, written into a test's temporary folder (never installed): the policies the certify tests load
by ``_target_``, and the TorchScript and ONNX files of one plain torch module."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

PACKAGE = "h50_user_policies"
SOURCE = textwrap.dedent(
    '''
    """Policies as a user writes them: only uqdrive.policy.interface.Action from uqdrive."""

    import numpy as np

    from uqdrive.policy.interface import Action

    CENTRES = np.round(np.linspace(-1.0, 1.0, 21), 1)


    class LaneKeeper:
        """Steers back to the lane centre from the world's info (no camera)."""

        needs_camera = False

        def __init__(self, kp: float = 3.0, kd: float = 1.0, hz: float = 15.0):
            self.kp, self.kd, self.hz = kp, kd, hz

        def reset(self, seed):
            self.previous = None

        def act(self, frame, info):
            lat = info["lateral_deviation"]
            previous = lat if self.previous is None else self.previous
            self.previous = lat
            return Action(max(-1.0, min(1.0, -self.kp * lat - self.kd * (lat - previous) * self.hz)))


    class BayesianKeeper(LaneKeeper):
        """The lane keeper with n draws of class probabilities around its decision, from the episode's seed."""

        def __init__(self, draws: int = 16, spread: float = 0.05, **kwargs):
            super().__init__(**kwargs)
            self.draws, self.spread = draws, spread

        def reset(self, seed):
            super().reset(seed)
            self.rng = np.random.default_rng(seed)

        def act(self, frame, info):
            steer = super().act(frame, info).steer
            logits = -((CENTRES - steer) ** 2) / self.spread + self.rng.normal(0, 1.5, (self.draws, len(CENTRES)))
            probs = np.exp(logits - logits.max(1, keepdims=True))
            return Action(steer, draws=probs / probs.sum(1, keepdims=True))


    class LinearLogits:
        """Class logits W x + b of the network's grey input, in numpy: the torch module `linear_module` computes."""

        def __init__(self, weights: str):
            data = np.load(weights)
            self.w, self.b = data["w"], data["b"]

        def reset(self, seed):
            pass

        def act(self, frame, info):
            import cv2

            gray = cv2.resize(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY), (64, 48), interpolation=cv2.INTER_AREA)
            x = gray.astype(np.float32).reshape(-1) / np.float32(255.0)
            return Action(float(CENTRES[int(np.argmax(self.w @ x + self.b))]))


    class BadAction:
        """Answers wrongly: ``what`` is steer (out of range), draws (of the wrong width) or type (not an Action)."""

        needs_camera = False

        def __init__(self, what: str):
            self.what = what

        def reset(self, seed):
            pass

        def act(self, frame, info):
            if self.what == "steer":
                return Action(2.0)
            if self.what == "draws":
                return Action(0.0, draws=np.full((4, 7), 1 / 7))
            return 0.0


    class FailsAtStep:
        """Raises at step ``step`` of every episode."""

        needs_camera = False

        def __init__(self, step: int = 5):
            self.step = step

        def reset(self, seed):
            self.t = 0

        def act(self, frame, info):
            self.t += 1
            if self.t > self.step:
                raise ZeroDivisionError("the user's bug")
            return Action(0.0)
    '''
)


def write_package(root: Path, monkeypatch: pytest.MonkeyPatch, package: str = PACKAGE, on_path: bool = True) -> Path:
    """The package under ``root``, importable for this test only (``on_path``; else from where a YAML lies beside
    it); returns its policies module's file."""
    folder = root / package
    folder.mkdir(parents=True)
    (folder / "__init__.py").write_text("")
    (folder / "policies.py").write_text(SOURCE)
    if on_path:
        monkeypatch.syspath_prepend(str(root))
    monkeypatch.setattr(sys, "path", list(sys.path))  # a folder the loader appends is dropped after the test
    for name in [n for n in sys.modules if n.startswith(package)]:
        monkeypatch.delitem(sys.modules, name)
    return folder / "policies.py"


def write_yaml(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def linear_module(seed: int = 0, classes: int = 21) -> torch.nn.Module:
    """A plain torch module from the grey frame [B, 1, 48, 64] to class logits, weights drawn from ``seed``."""
    torch.manual_seed(seed)
    module = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(48 * 64, classes))
    with torch.no_grad():
        module[1].weight.mul_(20.0)  # logits that change class from frame to frame
    return module.eval()


def save_weights(module: torch.nn.Module, path: Path) -> Path:
    linear = module[1]
    np.savez(path, w=linear.weight.detach().numpy(), b=linear.bias.detach().numpy())
    return path


def save_torchscript(module: torch.nn.Module, path: Path) -> Path:
    torch.jit.save(torch.jit.script(module), str(path))
    return path


def save_onnx(module: torch.nn.Module, path: Path) -> Path:
    x = torch.zeros(1, 1, 48, 64)
    dynamic = {"frames": {0: "batch"}, "out": {0: "batch"}}
    torch.onnx.export(
        module, (x,), str(path), dynamo=False, input_names=["frames"], output_names=["out"], dynamic_axes=dynamic
    )
    return path


class Constant(torch.nn.Module):
    """Steering (or logits) of a fixed value and width, whatever the frame."""

    def __init__(self, value: float, width: int = 1):
        super().__init__()
        self.value, self.width = value, width

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.full((x.shape[0], self.width), self.value)
