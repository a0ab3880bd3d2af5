"""A network file as a `Policy`: a TorchScript module (``torch.jit.save``) or an ONNX model, from frames to
class logits [B, C] (over the configured steering classes) or steering [B, 1] in [-1, 1].

The frame reaches the network as uqdrive's own networks see it (``input: gray``: [B, 1, 48, 64] float in [0, 1],
`uqdrive.network_input`) or as rendered (``input: rgb``: [B, 3, H, W] float in [0, 1]). Logits decide by their
arg-max class centre; steering is applied as it comes. With ``mc_draws: n`` a TorchScript module's dropout stays on
and each frame takes 2n passes in one batch: the first n decide (the mode of their mean probabilities, or their
mean steering) and the other n are the `Action`'s draws, so η̂2 counts draws apart from those that chose the
decision. The dropout masks come from torch's generator seeded by the episode's seed and the frame's index: the
same rollout draws the same masks in any process. ONNX runs in inference mode (no dropout): no draws.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from uqdrive.data.datasets import to_inputs
from uqdrive.network_input import preprocess_frame
from uqdrive.policy.interface import Action
from uqdrive.policy.slots import PolicyFailure

Output = Literal["auto", "logits", "steering"]
FrameInput = Literal["gray", "rgb"]
ONNX_MISSING = "an ONNX policy needs onnxruntime, which is not installed: pip install 'uqdrive[onnx]'"


def network_input(frame: np.ndarray | None, kind: FrameInput) -> np.ndarray:
    """The frame as the network takes it, batch of one: gray [1, 1, 48, 64] or rgb [1, 3, H, W], float in [0, 1]."""
    if frame is None:
        raise ValueError("a network policy needs the camera frame (render=True)")
    if kind == "gray":
        return to_inputs(preprocess_frame(frame)[None]).numpy()
    return (np.ascontiguousarray(frame.transpose(2, 0, 1))[None] / np.float32(255.0)).astype(np.float32)


class TensorPolicy(ABC):
    """Frames → a network's output → an `Action` (see the module); subclasses give `run` on a batch."""

    needs_camera = True

    def __init__(self, path: str, centres: np.ndarray, output: Output, frame_input: FrameInput, mc_draws: int):
        self.path, self.centres = str(path), np.asarray(centres, dtype=np.float64)
        self.output, self.frame_input, self.mc_draws = output, frame_input, int(mc_draws)
        self.seed, self.frame = 0, -1

    @abstractmethod
    def run(self, x: np.ndarray, draws: int) -> np.ndarray:
        """The network's output on the batch ``x`` ([2·draws, …] with MC dropout on, else [1, …])."""

    def reset(self, seed: int) -> None:
        self.seed, self.frame = int(seed), -1

    def act(self, frame: np.ndarray | None, info: dict) -> Action:
        self.frame += 1
        x = network_input(frame, self.frame_input)
        n = self.mc_draws
        out = self._shaped(self.run(np.repeat(x, 2 * n, axis=0) if n else x, n))
        if self.kind(out) == "steering":
            steer = out[:, 0].astype(np.float64)
            return Action(float(steer[:n].mean()), draws=steer[n:]) if n else Action(float(steer[0]))
        probs = torch.softmax(torch.as_tensor(out, dtype=torch.float64), dim=1).numpy()
        decision = float(self.centres[int(probs[: max(n, 1)].mean(0).argmax())])
        return Action(decision, draws=probs[n:]) if n else Action(decision)

    def _shaped(self, out: np.ndarray) -> np.ndarray:
        """[B, K] from [B, K] or [B]; any other shape, or a non-finite value, fails naming the file."""
        out = np.asarray(out)
        out = out[:, None] if out.ndim == 1 else out
        if out.ndim != 2:
            raise PolicyFailure(f"{self.path}: {self.expected()}, got output of shape {tuple(out.shape)}")
        if not np.isfinite(out).all():
            raise PolicyFailure(f"{self.path}: {self.expected()}, got non-finite values")
        return out

    def expected(self) -> str:
        classes = len(self.centres)
        return {
            "logits": f"expected [batch, {classes}] class logits",
            "steering": "expected [batch, 1] steering in [-1, 1]",
        }.get(self.output, f"expected [batch, {classes}] class logits or [batch, 1] steering in [-1, 1]")

    def kind(self, out: np.ndarray) -> Literal["logits", "steering"]:
        """What the output is: as configured, or by its width (1: steering; the class count: logits)."""
        width, classes = out.shape[1], len(self.centres)
        if self.output in ("auto", "steering") and width == 1:
            if np.abs(out).max() > 1.0:
                raise PolicyFailure(f"{self.path}: {self.expected()}, got steering {float(np.abs(out).max())!r}")
            return "steering"
        if self.output in ("auto", "logits") and width == classes:
            return "logits"
        raise PolicyFailure(f"{self.path}: {self.expected()}, got output of shape {tuple(out.shape)}")


class TorchScriptPolicy(TensorPolicy):
    """A ``torch.jit.save``d module; with ``mc_draws`` its dropout is on (it must have dropout). ``module``: the
    file already loaded (the slots of a worker share one copy: a slot's state is its seed and frame alone)."""

    def __init__(
        self,
        path: str,
        centres: np.ndarray,
        output: Output,
        frame_input: FrameInput,
        mc_draws: int = 0,
        module: torch.jit.ScriptModule | None = None,
    ):
        super().__init__(path, centres, output, frame_input, mc_draws)
        self.module = module if module is not None else load_torchscript(path)
        if mc_draws and not any("Dropout" in getattr(m, "original_name", "") for m in self.module.modules()):
            raise PolicyFailure(f"{path}: mc_draws={mc_draws} needs dropout in the module, and it has none")
        self.module.train(bool(mc_draws))

    @classmethod
    def loader(cls, path: str, *settings) -> Callable[[], TorchScriptPolicy]:
        """Slot instances sharing one load of ``path``."""
        module = load_torchscript(path)
        return lambda: cls(path, *settings, module=module)

    @torch.inference_mode()
    def run(self, x: np.ndarray, draws: int) -> np.ndarray:
        if not draws:
            return self.module(torch.from_numpy(x)).numpy()
        with torch.random.fork_rng(devices=[]):  # the masks from this frame's own seed; the global state kept
            torch.manual_seed(int(np.random.SeedSequence([self.seed, self.frame]).generate_state(1)[0]))
            return self.module(torch.from_numpy(x)).numpy()


class OnnxPolicy(TensorPolicy):
    """An ONNX model through onnxruntime (one CPU thread: parallelism is across workers); ``session``: shared."""

    def __init__(
        self, path: str, centres: np.ndarray, output: Output, frame_input: FrameInput, mc_draws: int = 0, session=None
    ):
        if mc_draws:
            raise PolicyFailure(f"{path}: mc_draws={mc_draws}: ONNX runs without dropout; save it as TorchScript")
        super().__init__(path, centres, output, frame_input, 0)
        self.session = session if session is not None else load_onnx(path)
        self.input_name = self.session.get_inputs()[0].name

    @classmethod
    def loader(cls, path: str, *settings) -> Callable[[], OnnxPolicy]:
        """Slot instances sharing one session of ``path``."""
        centres, output, frame_input, mc_draws = settings
        session = None if mc_draws else load_onnx(path)  # mc_draws: refused by the first instance, before loading
        return lambda: cls(path, centres, output, frame_input, mc_draws, session=session)

    def run(self, x: np.ndarray, draws: int) -> np.ndarray:
        return self.session.run(None, {self.input_name: x})[0]


def load_torchscript(path: str | Path) -> torch.jit.ScriptModule:
    """The module, or one line naming the file and what it is instead."""
    try:
        return torch.jit.load(str(path), map_location="cpu")
    except Exception as err:  # torch raises RuntimeError, ValueError or pickle errors for a file of another kind
        raise PolicyFailure(f"{path}: expected a TorchScript module (torch.jit.save), got {first_line(err)}") from None


def load_onnx(path: str | Path):
    """The onnxruntime session, or one line naming the file and what it is instead."""
    try:
        import onnxruntime
    except ImportError:
        raise PolicyFailure(ONNX_MISSING) from None
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    try:
        return onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as err:  # onnxruntime's own exception types
        raise PolicyFailure(f"{path}: expected an ONNX model, got {first_line(err)}") from None


def first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0][:200]}" if text else type(err).__name__
