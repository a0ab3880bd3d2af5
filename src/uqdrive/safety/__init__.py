"""Closed-loop probabilistic safety η1: controllers, safe sets, rollouts, parallel executors, sweep cells.

Composes `sim` (the world), `models` (the posteriors) and `uq` (measures and estimators).
"""

from uqdrive.safety.cells import SCHEMES, EstimatorSettings, cell_hash, estimate_safety, reusable_result
from uqdrive.safety.controller import AutopilotPolicy, Command, ConstantPolicy, Controller, Policy
from uqdrive.safety.executors import (BACKENDS, Executor, PolicySpec, ProcessExecutor, RayExecutor, RolloutJob,
                                      RolloutWorker, make_executor)
from uqdrive.safety.rollout import RolloutResult, run_rollout
from uqdrive.safety.safe_sets import SafeSet, Verdict, safe_set_for

__all__ = [
    "BACKENDS",
    "SCHEMES",
    "AutopilotPolicy",
    "Command",
    "ConstantPolicy",
    "Controller",
    "EstimatorSettings",
    "Executor",
    "Policy",
    "PolicySpec",
    "ProcessExecutor",
    "RayExecutor",
    "RolloutJob",
    "RolloutResult",
    "RolloutWorker",
    "SafeSet",
    "Verdict",
    "cell_hash",
    "estimate_safety",
    "make_executor",
    "reusable_result",
    "run_rollout",
    "safe_set_for",
]
