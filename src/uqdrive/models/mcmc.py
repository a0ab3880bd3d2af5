"""Hamiltonian Monte Carlo (Neal 2011) for any differentiable log-density, chains run as a batch.

Generic on purpose: the same kernel samples the steering head and, in the tests, a Bayesian
linear regression whose posterior is known in closed form. L leapfrog steps, Metropolis
accept/reject, step size tuned per chain by dual averaging (Hoffman & Gelman 2014) during
warm-up and jittered ±10% per proposal (breaks periodic trajectories). With `adapt_mass`, a
diagonal mass matrix per chain is set to the inverse of the variances the chain showed in the
middle half of warm-up (Stan's regularised estimate), then the step size adapts again: the
head's weights differ in scale by orders of magnitude, and one step size for all of them is
what kept the identity-mass chains from moving.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from tqdm import trange

LogProbGrad = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
"""θ [chains, D] → (log density [chains], its gradient [chains, D])."""

Callback = Callable[[int, torch.Tensor, torch.Tensor, torch.Tensor], None]
"""(iteration, θ [chains, D], log density [chains], acceptance probability [chains]) after each iteration."""


@dataclass(frozen=True)
class HMCResult:
    samples: torch.Tensor  # [chains, kept, D]
    log_prob: torch.Tensor  # [chains, kept]
    accept_rate: torch.Tensor  # [chains], mean acceptance probability after warm-up
    step_size: torch.Tensor  # [chains], the adapted step size used after warm-up


@dataclass(frozen=True)
class _Point:
    """A chain batch's position θ [chains, D] with its log density and gradient."""

    theta: torch.Tensor
    lp: torch.Tensor
    grad: torch.Tensor


class HMCKernel:
    """One Metropolis-corrected HMC transition per call (Pyro's `HMC` names the same steps): a jittered step size,
    a momentum draw for the mass matrix, L leapfrog steps, the accept test. Every draw comes from ``generator``, in
    this order per transition: jitter, momentum, acceptance."""

    def __init__(self, log_prob_grad: LogProbGrad, leapfrog_steps: int, generator: torch.Generator | None):
        self.log_prob_grad, self.leapfrog_steps, self.generator = log_prob_grad, leapfrog_steps, generator

    def start(self, init: torch.Tensor) -> _Point:
        theta = init.detach().clone()
        lp, grad = self.log_prob_grad(theta)
        if not torch.isfinite(lp).all():
            raise ValueError("hmc: the log density is not finite at the initial point")
        return _Point(theta, lp, grad)

    def jittered(self, step_size: torch.Tensor) -> torch.Tensor:
        """The step size ±10 % per chain and proposal, so no trajectory length stays periodic: [chains, 1]."""
        chains = step_size.shape[0]
        return (step_size * (1.0 + 0.2 * (torch.rand(chains, generator=self.generator) - 0.5))).unsqueeze(1)

    def momentum(self, shape: torch.Size, inv_mass: torch.Tensor) -> torch.Tensor:
        return torch.randn(shape, generator=self.generator) / inv_mass.sqrt()

    def leapfrog(self, start: _Point, p0: torch.Tensor, e: torch.Tensor, inv_mass: torch.Tensor):
        """L leapfrog steps from ``start`` with momentum ``p0``: the proposal and its final momentum."""
        p = p0 + 0.5 * e * start.grad
        theta = start.theta
        for step in range(self.leapfrog_steps):
            theta = theta + e * inv_mass * p
            lp, grad = self.log_prob_grad(theta)
            p = p + (e if step < self.leapfrog_steps - 1 else 0.5 * e) * grad
        return _Point(theta, lp, grad), p

    def accept(self, current: _Point, proposal: _Point, log_ratio: torch.Tensor) -> tuple[_Point, torch.Tensor]:
        """Metropolis: each chain moves to its proposal with probability min(1, exp(log_ratio)); NaN never moves."""
        log_ratio = torch.nan_to_num(log_ratio, nan=-math.inf)
        accept_prob = log_ratio.clamp(max=0.0).exp()
        moved = torch.log(torch.rand(current.lp.shape[0], generator=self.generator)) < log_ratio
        point = _Point(
            torch.where(moved.unsqueeze(1), proposal.theta, current.theta),
            torch.where(moved, proposal.lp, current.lp),
            torch.where(moved.unsqueeze(1), proposal.grad, current.grad),
        )
        return point, accept_prob

    def transition(self, current: _Point, step_size: torch.Tensor, inv_mass: torch.Tensor):
        e = self.jittered(step_size)
        p0 = self.momentum(current.theta.shape, inv_mass)
        proposal, p = self.leapfrog(current, p0, e, inv_mass)
        kinetic = 0.5 * ((inv_mass * p.square()).sum(1) - (inv_mass * p0.square()).sum(1))
        return self.accept(current, proposal, proposal.lp - current.lp - kinetic)


class _WarmUp:
    """Warm-up's adaptation: the step size by dual averaging towards the target acceptance; with a mass window, a
    diagonal mass matrix from the variances the chains showed in it, then the step size adapts again."""

    def __init__(self, chains: int, shape: torch.Size, step_size: float, target: float, warmup: int, adapt_mass: bool):
        self.target, self.warmup = target, warmup
        self.adapt = _DualAveraging(torch.full((chains,), float(step_size)), target)
        self.step_size = self.adapt.step_size
        self.inv_mass = torch.ones(shape)
        self.window = (warmup // 4, warmup * 3 // 4) if adapt_mass and warmup >= 40 else None  # short: identity
        self.moments = _Welford(shape)

    def update(self, it: int, theta: torch.Tensor, accept_prob: torch.Tensor) -> None:
        self.step_size = self.adapt.update(accept_prob)
        if self.window and self.window[0] <= it < self.window[1]:
            self.moments.add(theta)
        if self.window and it == self.window[1] - 1:
            self.inv_mass = self.moments.regularised_variance()
            self.adapt = _DualAveraging(self.step_size, self.target)  # the step size that fits the new metric differs
        if it == self.warmup - 1:
            self.step_size = self.adapt.final()


def _check(num_samples: int, warmup: int, thin: int, leapfrog_steps: int, step_size: float, target: float) -> None:
    if num_samples < 1 or warmup < 0 or thin < 1 or leapfrog_steps < 1 or not step_size > 0:
        raise ValueError(
            f"hmc: num_samples={num_samples} ≥ 1, warmup={warmup} ≥ 0, thin={thin} ≥ 1, "
            f"leapfrog_steps={leapfrog_steps} ≥ 1 and step_size={step_size} > 0 required"
        )
    if not 0 < target < 1:
        raise ValueError(f"hmc: target_accept={target} must lie in (0, 1)")


def hmc(
    log_prob_grad: LogProbGrad,
    init: torch.Tensor,
    *,
    num_samples: int,
    warmup: int,
    thin: int = 1,
    leapfrog_steps: int = 10,
    step_size: float = 0.01,
    target_accept: float = 0.75,
    adapt_mass: bool = False,
    generator: torch.Generator | None = None,
    callback: Callback | None = None,
    progress: bool = False,
    desc: str = "hmc",
) -> HMCResult:
    """Run len(init) chains for warmup + num_samples·thin iterations; keep every thin-th after warm-up."""
    _check(num_samples, warmup, thin, leapfrog_steps, step_size, target_accept)
    kernel = HMCKernel(log_prob_grad, leapfrog_steps, generator)
    point = kernel.start(init)
    chains = point.theta.shape[0]
    tuning = _WarmUp(chains, point.theta.shape, step_size, target_accept, warmup, adapt_mass)
    kept, kept_lp, accept_sum = [], [], torch.zeros(chains)
    for it in trange(warmup + num_samples * thin, desc=desc, unit="it", disable=not progress):
        point, accept_prob = kernel.transition(point, tuning.step_size, tuning.inv_mass)
        if it < warmup:
            tuning.update(it, point.theta, accept_prob)
        else:
            accept_sum += accept_prob
            if (it - warmup + 1) % thin == 0:
                kept.append(point.theta.clone())
                kept_lp.append(point.lp.clone())
        if callback is not None:
            callback(it, point.theta, point.lp, accept_prob)
    return HMCResult(torch.stack(kept, 1), torch.stack(kept_lp, 1), accept_sum / (num_samples * thin), tuning.step_size)


def whitened(log_prob_grad: LogProbGrad, centre: torch.Tensor, scale: torch.Tensor) -> LogProbGrad:
    """The same density in coordinates u with θ = centre + scale·u (scale [D, D], e.g. the Cholesky factor of a
    Laplace covariance): HMC on u with identity mass is HMC on θ with the dense mass matrix (scale·scaleᵀ)⁻¹."""

    def log_prob_grad_u(u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        lp, grad = log_prob_grad(centre + u @ scale.T)
        return lp, grad @ scale

    return log_prob_grad_u


class _Welford:
    """Running mean and variance per chain and coordinate."""

    def __init__(self, shape: torch.Size) -> None:
        self.count, self.mean, self.m2 = (
            0,
            torch.zeros(shape, dtype=torch.float64),
            torch.zeros(shape, dtype=torch.float64),
        )

    def add(self, x: torch.Tensor) -> None:
        self.count += 1
        delta = x.double() - self.mean
        self.mean += delta / self.count
        self.m2 += delta * (x.double() - self.mean)

    def regularised_variance(self) -> torch.Tensor:
        """Stan's shrinkage towards 1e-3: (n/(n+5))·var + 1e-3·5/(n+5)."""
        n = self.count
        var = self.m2 / max(n - 1, 1)
        return ((n / (n + 5.0)) * var + 1e-3 * 5.0 / (n + 5.0)).float()


class _DualAveraging:
    """Nesterov dual averaging of log step size towards a target acceptance (Hoffman & Gelman, Alg. 5)."""

    def __init__(
        self, step_size: torch.Tensor, target: float, gamma: float = 0.05, t0: float = 10.0, kappa: float = 0.75
    ) -> None:
        self.step_size, self.target, self.gamma, self.t0, self.kappa = step_size, target, gamma, t0, kappa
        self.mu = torch.log(10.0 * step_size)
        self.h_bar = torch.zeros_like(step_size)
        self.log_bar = torch.log(step_size)
        self.m = 0

    def update(self, accept_prob: torch.Tensor) -> torch.Tensor:
        self.m += 1
        w = 1.0 / (self.m + self.t0)
        self.h_bar = (1 - w) * self.h_bar + w * (self.target - accept_prob)
        log_eps = self.mu - math.sqrt(self.m) / self.gamma * self.h_bar
        eta = self.m**-self.kappa
        self.log_bar = eta * log_eps + (1 - eta) * self.log_bar
        return log_eps.exp()

    def final(self) -> torch.Tensor:
        """The averaged step size, used for every iteration after warm-up."""
        return self.log_bar.exp() if self.m else self.step_size


def split_rhat(samples: torch.Tensor) -> torch.Tensor:
    """Split-R̂ (Gelman et al., BDA3) per coordinate of samples [chains, S, D] (or [chains, S]); needs S ≥ 4."""
    squeeze = samples.ndim == 2
    x = samples.unsqueeze(-1) if squeeze else samples
    half = x.shape[1] // 2
    if half < 2:
        raise ValueError(f"split_rhat needs at least 4 samples per chain, got {x.shape[1]}")
    x = torch.cat([x[:, :half], x[:, -half:]], 0).double()  # [2·chains, half, D]
    within = x.var(1, unbiased=True).mean(0)
    between = half * x.mean(1).var(0, unbiased=True)
    var_plus = (half - 1) / half * within + between / half
    rhat = torch.sqrt(var_plus / within.clamp_min(1e-300)).float()
    return rhat.squeeze(-1) if squeeze else rhat
