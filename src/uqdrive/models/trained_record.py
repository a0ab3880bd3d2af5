"""A trained controller's record: metrics/<experiment>/train/<method>/seed<r>.json, written by the train stage and
read by the report."""

from __future__ import annotations

from typing import Any

from uqdrive.records import extra_keys, record


@record(open_keys=True)
class TrainMetrics:
    """A trained controller's validation metrics; each method adds its own keys (HMC its convergence
    diagnostics, MCD its dropout rates), kept and read by `get`."""

    method: str
    val_accuracy: float
    val_nll: float
    val_ece: float
    val_brier: float
    majority_baseline_accuracy: float
    train_frames: int
    val_frames: int
    eval_samples: int
    seed: int
    train_seconds: float
    diagnostics: str

    def get(self, key: str) -> Any:
        return extra_keys(self).get(key)
