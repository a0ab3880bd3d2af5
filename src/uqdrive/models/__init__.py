"""Bayesian steering controllers: a PilotNet trunk and Bayesian heads (MCD, VI, HMC, deep ensemble,
last-layer Laplace, or a user's own) behind one `Posterior` interface."""

from uqdrive.models.checkpoint import load_posterior, save_posterior
from uqdrive.models.posterior import Posterior

__all__ = ["Posterior", "load_posterior", "save_posterior"]
