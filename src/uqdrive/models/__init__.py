"""Bayesian steering controllers: a PilotNet trunk and MCD, VI or HMC heads behind one `Posterior` interface."""

from uqdrive.models.checkpoint import load_posterior, save_posterior
from uqdrive.models.posterior import Posterior

__all__ = ["Posterior", "load_posterior", "save_posterior"]
