"""Fitting the three posteriors: MCD end to end on frames; VI and HMC on cached trunk features.

VI and HMC only ever see the MCD trunk's features, which are fixed, so `compute_features`
runs the convolutions once per data set and every epoch / leapfrog step reuses the tensor.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch.nn.functional import cross_entropy
from tqdm import trange

from uqdrive.checks import ConfigError
from uqdrive.data.datasets import FrameSet
from uqdrive.models.hmc import HMCPosterior, flatten_mcd_head, head_log_posterior, unflatten
from uqdrive.models.mcd import MCDPosterior
from uqdrive.models.mcmc import LogProbGrad, hmc, split_rhat
from uqdrive.models.metrics import classification_metrics
from uqdrive.models.pilotnet import sampled_mlp_logits
from uqdrive.models.posterior import Posterior
from uqdrive.models.vi import VIPosterior

EVAL_CHUNK = 2048  # frames per head evaluation: bounds memory at n draws x chunk x classes


def _require(name: str, value: float, ok: bool, allowed: str) -> None:
    if not ok:
        raise ConfigError(f"model.{name}={value!r} is invalid: must be {allowed}")


@dataclass(frozen=True)
class MCDSettings:
    epochs: int
    batch_size: int
    lr: float
    init_p: float = 0.1
    temperature: float = 0.1
    lengthscale: float = 1e-4  # prior length scale l of concrete dropout's weight term l²/N

    def __post_init__(self) -> None:
        _require("epochs", self.epochs, self.epochs >= 1, "≥ 1")
        _require("batch_size", self.batch_size, self.batch_size >= 1, "≥ 1")
        _require("lr", self.lr, self.lr > 0, "> 0")
        _require("init_p", self.init_p, 0 < self.init_p < 1, "in (0, 1)")
        _require("temperature", self.temperature, self.temperature > 0, "> 0")
        _require("lengthscale", self.lengthscale, self.lengthscale >= 0, "≥ 0")


@dataclass(frozen=True)
class VISettings:
    epochs: int
    batch_size: int
    lr: float
    prior_sigma: float = 1.0
    init_sigma: float = 0.01

    def __post_init__(self) -> None:
        _require("epochs", self.epochs, self.epochs >= 1, "≥ 1")
        _require("batch_size", self.batch_size, self.batch_size >= 1, "≥ 1")
        _require("lr", self.lr, self.lr > 0, "> 0")
        _require("prior_sigma", self.prior_sigma, self.prior_sigma > 0, "> 0")
        _require("init_sigma", self.init_sigma, self.init_sigma > 0, "> 0")


@dataclass(frozen=True)
class HMCSettings:
    chains: int
    samples: int  # kept per chain
    warmup: int  # burn-in iterations, during which the step size adapts
    thin: int = 1
    leapfrog_steps: int = 10
    step_size: float = 1e-3  # initial; adapted during warm-up
    target_accept: float = 0.75
    prior_sigma: float = 1.0
    map_steps: int = 200  # full-batch Adam steps from the MCD head towards the MAP before sampling
    map_lr: float = 1e-3
    init_jitter: float = 1e-3  # std of the per-chain perturbation of the start, so chains differ

    def __post_init__(self) -> None:
        _require("chains", self.chains, self.chains >= 2, "≥ 2 (R-hat compares chains)")
        _require("samples", self.samples, self.samples >= 4, "≥ 4 (split R-hat needs them)")
        _require("warmup", self.warmup, self.warmup >= 0, "≥ 0")
        _require("thin", self.thin, self.thin >= 1, "≥ 1")
        _require("leapfrog_steps", self.leapfrog_steps, self.leapfrog_steps >= 1, "≥ 1")
        _require("step_size", self.step_size, self.step_size > 0, "> 0")
        _require("target_accept", self.target_accept, 0 < self.target_accept < 1, "in (0, 1)")
        _require("prior_sigma", self.prior_sigma, self.prior_sigma > 0, "> 0")
        _require("map_steps", self.map_steps, self.map_steps >= 0, "≥ 0")
        _require("map_lr", self.map_lr, self.map_lr > 0, "> 0")
        _require("init_jitter", self.init_jitter, self.init_jitter >= 0, "≥ 0")


def settings_from(cls: type, values: dict) -> MCDSettings | VISettings | HMCSettings:
    """Build a settings object from a config section, naming any unknown key."""
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ConfigError(f"unknown model keys {unknown} for {cls.__name__}; allowed: {sorted(known)}")
    return cls(**values)


@torch.no_grad()
def compute_features(posterior: Posterior, frames: FrameSet, batch_size: int = 512) -> torch.Tensor:
    """Trunk outputs [N, F] of every frame, in order: the cache VI and HMC train on."""
    return torch.cat([posterior.features(x) for x, _ in frames.batches(batch_size)])


@torch.no_grad()
def evaluate(posterior: Posterior, features: torch.Tensor, labels: torch.Tensor, n: int,
             generator: torch.Generator) -> dict[str, float]:
    """Metrics of the posterior predictive (mean of n draws' probabilities) on cached features."""
    probs = torch.cat([posterior.head_probs(f, n, generator).mean(0) for f in features.split(EVAL_CHUNK)])
    return classification_metrics(probs, labels)


def train_mcd(model: MCDPosterior, train: FrameSet, val: FrameSet, settings: MCDSettings,
              generator: torch.Generator, eval_samples: int, progress: bool = False) -> list[dict]:
    """Adam on cross-entropy + concrete dropout regulariser; returns one learning-curve row per epoch."""
    optimizer = torch.optim.Adam(model.parameters(), lr=settings.lr)
    curve = []
    for epoch in trange(1, settings.epochs + 1, desc="mcd", unit="epoch", disable=not progress):
        model.train()
        total = 0.0
        for x, y in train.batches(settings.batch_size, generator):
            loss = cross_entropy(model.train_logits(x, generator), y) + model.regularizer(len(train), settings.lengthscale)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += loss.item() * len(y)
        model.eval()
        scores = evaluate(model, compute_features(model, val), val.labels, eval_samples, generator)
        rates = {f"dropout_p{k + 1}": p for k, p in enumerate(model.dropout_rates())}
        curve.append({"step": epoch, "train_loss": total / len(train), "val_accuracy": scores["accuracy"],
                      "val_nll": scores["nll"], **rates})
    model.requires_grad_(False)
    return curve


def train_vi(vi: VIPosterior, train_features: torch.Tensor, train_labels: torch.Tensor, val_features: torch.Tensor,
             val_labels: torch.Tensor, settings: VISettings, generator: torch.Generator, eval_samples: int,
             progress: bool = False) -> list[dict]:
    """Maximise the ELBO (per frame: expected log-likelihood − KL/N) by Adam with one draw per step."""
    optimizer = torch.optim.Adam(vi.head_parameters(), lr=settings.lr)
    n_train = len(train_labels)
    curve = []
    for epoch in trange(1, settings.epochs + 1, desc="vi", unit="epoch", disable=not progress):
        total = 0.0
        for index in torch.randperm(n_train, generator=generator).split(settings.batch_size):
            logits = vi.head_logits(train_features[index], 1, generator)[0]
            loss = cross_entropy(logits, train_labels[index]) + vi.kl() / n_train
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += loss.item() * len(index)
        scores = evaluate(vi, val_features, val_labels, eval_samples, generator)
        curve.append({"step": epoch, "train_loss": total / n_train, "val_accuracy": scores["accuracy"],
                      "val_nll": scores["nll"], "sigma_mean": vi.posterior_sigma_mean()})
    vi.requires_grad_(False)
    return curve


def find_map(log_prob_grad: LogProbGrad, start: torch.Tensor, steps: int, lr: float, scale: int) -> torch.Tensor:
    """Full-batch Adam ascent of the log posterior (divided by `scale` = N for a well-scaled step)."""
    theta = start.clone().unsqueeze(0).requires_grad_(True)
    optimizer = torch.optim.Adam([theta], lr=lr)
    for _ in range(steps):
        _, grad = log_prob_grad(theta)
        theta.grad = -grad / scale
        optimizer.step()
    return theta.detach()[0]


def sample_hmc(mcd: MCDPosterior, train_features: torch.Tensor, train_labels: torch.Tensor,
               val_features: torch.Tensor, val_labels: torch.Tensor, settings: HMCSettings,
               generator: torch.Generator, progress: bool = False) -> tuple[HMCPosterior, dict, list[dict]]:
    """Full-batch HMC over the head, chains started at the MAP (from the MCD head) plus jitter.

    Returns the posterior (all kept samples of all chains), diagnostics (acceptance, split-R̂,
    step size) and a learning curve sampled about 100 times over the run.
    """
    shapes = mcd.arch.head_shapes(mcd.num_classes)
    n_train = len(train_labels)
    log_prob_grad = head_log_posterior(train_features, train_labels, shapes, settings.prior_sigma)
    start = find_map(log_prob_grad, flatten_mcd_head(mcd), settings.map_steps, settings.map_lr, n_train)
    init = start + settings.init_jitter * torch.randn((settings.chains, len(start)), generator=generator)
    total = settings.warmup + settings.samples * settings.thin
    every = max(1, total // 100)
    curve: list[dict] = []

    def record(it: int, theta: torch.Tensor, lp: torch.Tensor, accept_prob: torch.Tensor) -> None:
        if (it + 1) % every and it + 1 != total:
            return
        probs = torch.softmax(sampled_mlp_logits(val_features, unflatten(theta, shapes)), -1).mean(0)
        scores = classification_metrics(probs, val_labels)
        curve.append({"step": it + 1, "train_loss": float(-lp.mean()) / n_train, "val_accuracy": scores["accuracy"],
                      "val_nll": scores["nll"], "accept_prob": float(accept_prob.mean()),
                      "warmup": int(it < settings.warmup)})

    result = hmc(log_prob_grad, init, num_samples=settings.samples, warmup=settings.warmup, thin=settings.thin,
                 leapfrog_steps=settings.leapfrog_steps, step_size=settings.step_size,
                 target_accept=settings.target_accept, generator=generator, callback=record,
                 progress=progress, desc="hmc")
    rhat = split_rhat(result.samples)
    diagnostics = {
        "accept_rate": float(result.accept_rate.mean()),
        "accept_rate_min_chain": float(result.accept_rate.min()),
        "step_size": float(result.step_size.mean()),
        "rhat_max": float(rhat.max()),
        "rhat_median": float(rhat.median()),
        "rhat_log_prob": float(split_rhat(result.log_prob)),
        "kept_samples": int(result.samples.shape[0] * result.samples.shape[1]),
    }
    return HMCPosterior.from_samples(mcd, result.samples.flatten(0, 1)), diagnostics, curve
