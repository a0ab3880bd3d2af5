"""Training R replicates as one batched model: their parameters stacked on a leading replicate dimension.

Method-level answers average over training runs, so a method is trained R times (seeds). Stacked, one optimiser
step updates every replicate (Adam is elementwise, so a stacked step is each replicate's own step) and each layer is
one batched kernel: the trunk's convolutions one grouped convolution (a group per replicate), dense layers one
`baddbmm`. What a run pays besides arithmetic (Python, optimiser calls, small kernels) is then paid once; the
arithmetic is not shared, and the MCD trunk's convolutions, ~75% of a lone step, stay the floor (measured at R = 8:
an MCD step 1.2–1.45x cheaper per replicate, `uqdrive bench train`).

Replicate r stays the run a lone seed-r training is: every random number it uses (initialisation, data order,
noise) is drawn from its own generator, in the order its lone run draws them (`per_replicate`), never from a
shared stream. Only the float rounding of the batched kernels differs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence

import torch
from torch import nn
from torch.nn.functional import conv2d

from uqdrive.data.datasets import FrameSet, to_inputs
from uqdrive.models.pilotnet import Trunk

FEATURE_ROWS = 256  # frames x replicates per trunk pass over a split: oneDNN is fastest at a few hundred (measured:
# 512 frames a pass took twice as long per frame as 256, whose activations still fit the caches)


def per_replicate(
    generators: Sequence[torch.Generator], draw: Callable[[torch.Generator], torch.Tensor]
) -> torch.Tensor:
    """``draw(g)`` with each replicate's own generator, stacked [R, ...]: replicate r's numbers are those its lone
    run draws with the same call."""
    return torch.stack([draw(g) for g in generators])


def epoch_batches(count: int, batch_size: int, generators: Sequence[torch.Generator]) -> Iterator[torch.Tensor]:
    """One epoch's minibatch indices [R, b]: each replicate's own shuffle of range(count), split as
    `FrameSet.batches` splits it (the permutation drawn when the epoch starts)."""
    order = per_replicate(generators, lambda g: torch.randperm(count, generator=g))
    yield from order.split(batch_size, dim=1)


def replicate_rows(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Each replicate's rows of its own values [R, N, ...] at index [R, ...] (``values[r][index[r]]``, stacked)."""
    replicate = torch.arange(len(values)).view(-1, *[1] * (index.ndim - 1))
    return values[replicate, index]


def stack_parameters(modules: Sequence[nn.Module]) -> dict[str, torch.Tensor]:
    """The trainable parameters (those that require grad) of same-shaped modules stacked [R, ...] by name, as new
    leaf tensors that require grad; frozen ones (a head method's trunk) stay in the modules."""
    named = [{k: p for k, p in m.named_parameters() if p.requires_grad} for m in modules]
    return {name: torch.stack([n[name].detach() for n in named]).requires_grad_(True) for name in named[0]}


@torch.no_grad()
def unstack_into(params: dict[str, torch.Tensor], modules: Sequence[nn.Module]) -> None:
    """Copy replicate r's slice of every stacked parameter into ``modules[r]``."""
    for r, module in enumerate(modules):
        named = dict(module.named_parameters())
        for name, stacked in params.items():
            named[name].copy_(stacked[r])


def adam(params: Iterable[torch.Tensor], lr: float) -> torch.optim.Adam:
    """The optimiser of every stacked training: Adam, fused (one kernel over all tensors; on CPU 2-4x faster than
    the per-tensor loop, which at R = 8 cost 15 ms a step, more than the MCD head's forward and backward)."""
    return torch.optim.Adam(params, lr=lr, fused=True)


def stacked_linear(h: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """Each replicate's ``nn.Linear``: h [R, B, in], weight [R, out, in] (nn.Linear's layout), bias [R, out]."""
    return torch.baddbmm(bias.unsqueeze(1), h, weight.transpose(1, 2))


def stacked_trunk(trunk: Trunk, params: dict[str, torch.Tensor], frames: torch.Tensor) -> torch.Tensor:
    """Features [R, B, F] of R trunks shaped like ``trunk`` on frames [R, B, 1, 48, 64], replicate r's frames
    through trunk r, their parameters stacked in ``params`` under a Posterior's names (``trunk.convs.0.weight``, …).

    The convolutions run as one grouped convolution (replicate r's channels are group r) in channels-last memory,
    where oneDNN's kernels for these small channel counts are fastest (backward ~1.5x on the 24→36 layer).
    """
    replicates, batch = frames.shape[:2]
    h = frames.transpose(0, 1).flatten(1, 2)  # [B, R·C, H, W]
    for index, layer in enumerate(trunk.convs):
        if isinstance(layer, nn.Conv2d):
            h = h.contiguous(memory_format=torch.channels_last)
            weight = params[f"trunk.convs.{index}.weight"].flatten(0, 1)  # [R·O, C, k, k]
            if layer.in_channels > 1:  # (one input channel: the plain layout's kernel is the faster)
                weight = weight.contiguous(memory_format=torch.channels_last)
            bias = params[f"trunk.convs.{index}.bias"].flatten()
            h = conv2d(h, weight, bias, layer.stride, layer.padding, groups=replicates)
        elif isinstance(layer, nn.ReLU):
            h = torch.relu(h)
        elif not isinstance(layer, nn.Flatten):
            raise TypeError(f"stacked_trunk: no stacked form of {type(layer).__name__}")
    h = h.reshape(batch, replicates, -1).transpose(0, 1)  # [R, B, C·H·W], each replicate flattened as nn.Flatten
    return torch.relu(stacked_linear(h, params["trunk.fc.weight"], params["trunk.fc.bias"]))


@torch.no_grad()
def stacked_features(trunk: Trunk, params: dict[str, torch.Tensor], frames: FrameSet) -> torch.Tensor:
    """Every replicate's trunk features [R, N, F] of the same frames, in order (the replicates' `compute_features`)."""
    replicates = len(next(iter(params.values())))
    chunk = max(1, FEATURE_ROWS // replicates)
    parts = []
    for start in range(0, len(frames), chunk):
        x = to_inputs(frames.images[start : start + chunk])
        parts.append(stacked_trunk(trunk, params, x.expand(replicates, *x.shape)))
    return torch.cat(parts, 1)


def stacked_trunks(posteriors: Sequence[nn.Module]) -> dict[str, torch.Tensor]:
    """The trunk parameters of posteriors (frozen or not) stacked [R, ...] by name, for `stacked_features`."""
    named = [dict(p.named_parameters()) for p in posteriors]
    return {name: torch.stack([n[name].detach() for n in named]) for name in named[0] if name.startswith("trunk.")}
