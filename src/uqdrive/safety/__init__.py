"""Closed-loop probabilistic safety η1: controllers, safe sets, rollouts, parallel executors, sweep cells,
and the three-tier warning system on real-time decision confidence η2.

Composes `sim` (the world), `models` (the posteriors) and `uq` (measures and estimators).
"""

from uqdrive.safety.cells import EstimatorSettings, estimate_safety
from uqdrive.safety.controller import NO_WARNING, AutopilotPolicy, Command, ConstantPolicy, Controller, Policy
from uqdrive.safety.executors import (
    BACKENDS,
    Executor,
    LockstepExecutor,
    LockstepJob,
    PolicySpec,
    ProcessPool,
    RolloutJob,
    RolloutWorker,
    make_executor,
)
from uqdrive.safety.rollout import RolloutResult, run_rollout, run_rollouts
from uqdrive.safety.runner import CellRun, CellRunner
from uqdrive.safety.safe_sets import HANDOVER, SafeSet, Verdict, safe_set_for
from uqdrive.safety.warnings import (
    WarningAction,
    WarningActions,
    WarningConfig,
    WarningController,
    WarningRule,
    classify,
)

__all__ = [
    "BACKENDS",
    "HANDOVER",
    "NO_WARNING",
    "AutopilotPolicy",
    "CellRun",
    "CellRunner",
    "Command",
    "ConstantPolicy",
    "Controller",
    "EstimatorSettings",
    "Executor",
    "Policy",
    "PolicySpec",
    "ProcessPool",
    "LockstepExecutor",
    "LockstepJob",
    "RolloutJob",
    "RolloutResult",
    "RolloutWorker",
    "SafeSet",
    "Verdict",
    "WarningAction",
    "WarningActions",
    "WarningConfig",
    "WarningController",
    "WarningRule",
    "classify",
    "estimate_safety",
    "make_executor",
    "run_rollout",
    "run_rollouts",
    "safe_set_for",
]
