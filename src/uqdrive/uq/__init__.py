"""Uncertainty quantification: per-frame measures, Bernoulli-rate estimators with (θ, γ) guarantees and
sequential threshold tests with exact error.

Knows nothing of the simulator, data or models: it takes posterior class probabilities
``[n, B, C]`` and the class centres, or 0/1 outcomes.
Comparisons of cells on the same seeds: exact paired tests (`paired`), Bonferroni (`multiplicity`),
intervals over training replicates (`replicates`, `betting`); the two levels of answer: a family of findings for
these trained controllers (`family`) and method claims over training runs (`claims`), with their `verdict`;
Learn-then-Test (`ltt`); rare events over an operating domain — refutation by importance sampling with a bound valid
at any stopping time, certification at the zero-failure floor (`rare`, `rare_proposal`).

Names are imported from their modules when first asked for (`__getattr__`): a command that needs one part — the
certify gate's floor, a bound — does not pay for the rest (torch, which the per-frame measures import). The
sequential estimator is `uqdrive.uq.estimators.sequential`: here ``sequential`` is its scheme's module, which
importing it binds on the package, so no name here can mean both.
"""

from __future__ import annotations

import importlib

_HOME = {  # name → the module defining it
    "MeanInterval": "uqdrive.uq.betting",
    "mean_interval": "uqdrive.uq.betting",
    "chernoff_n": "uqdrive.uq.bounds",
    "clopper_pearson_interval": "uqdrive.uq.bounds",
    "clopper_pearson_n": "uqdrive.uq.bounds",
    "massart_n": "uqdrive.uq.bounds",
    "ClaimResult": "uqdrive.uq.claims",
    "MethodClaim": "uqdrive.uq.claims",
    "ScoreClaim": "uqdrive.uq.claims",
    "decide_claim": "uqdrive.uq.claims",
    "decide_claims": "uqdrive.uq.claims",
    "mean_verdicts": "uqdrive.uq.claims",
    "sign_runs_needed": "uqdrive.uq.claims",
    "Estimate": "uqdrive.uq.estimators",
    "SPRTResult": "uqdrive.uq.estimators",
    "chernoff": "uqdrive.uq.estimators",
    "clopper_pearson": "uqdrive.uq.estimators",
    "massart": "uqdrive.uq.estimators",
    "simulate_sprt": "uqdrive.uq.estimators",
    "sprt": "uqdrive.uq.estimators",
    "sprt_cap": "uqdrive.uq.estimators",
    "wilson": "uqdrive.uq.estimators",
    "Comparison": "uqdrive.uq.family",
    "Finding": "uqdrive.uq.family",
    "decide_finding": "uqdrive.uq.family",
    "decide_findings": "uqdrive.uq.family",
    "FrameMeasures": "uqdrive.uq.measures",
    "check_samples": "uqdrive.uq.measures",
    "decision": "uqdrive.uq.measures",
    "decision_confidence": "uqdrive.uq.measures",
    "draw_measures": "uqdrive.uq.measures",
    "expected_entropy": "uqdrive.uq.measures",
    "frame_measures": "uqdrive.uq.measures",
    "mutual_information": "uqdrive.uq.measures",
    "mutual_information_se": "uqdrive.uq.measures",
    "predictive_entropy": "uqdrive.uq.measures",
    "predictive_probs": "uqdrive.uq.measures",
    "sample_decisions": "uqdrive.uq.measures",
    "steering_moments": "uqdrive.uq.measures",
    "within_ball": "uqdrive.uq.measures",
    "split_gamma": "uqdrive.uq.multiplicity",
    "PairedTable": "uqdrive.uq.paired",
    "PairedTest": "uqdrive.uq.paired",
    "difference_interval": "uqdrive.uq.paired",
    "mcnemar_p": "uqdrive.uq.paired",
    "paired_table": "uqdrive.uq.paired",
    "paired_test": "uqdrive.uq.paired",
    "share_interval": "uqdrive.uq.paired",
    "ReplicateInterval": "uqdrive.uq.replicates",
    "replicate_bounded_interval": "uqdrive.uq.replicates",
    "replicate_t_interval": "uqdrive.uq.replicates",
    "SequentialScheme": "uqdrive.uq.sequential",
    "sequential_scheme": "uqdrive.uq.sequential",
    "ThresholdDecision": "uqdrive.uq.threshold",
    "ThresholdTest": "uqdrive.uq.threshold",
    "doubling_looks": "uqdrive.uq.threshold",
    "Reason": "uqdrive.uq.verdict",
    "Verdict": "uqdrive.uq.verdict",
}


def __getattr__(name: str):
    module = _HOME.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_HOME})


__all__ = [
    "Estimate",
    "FrameMeasures",
    "SPRTResult",
    "SequentialScheme",
    "ThresholdDecision",
    "ThresholdTest",
    "check_samples",
    "chernoff",
    "chernoff_n",
    "clopper_pearson",
    "clopper_pearson_interval",
    "clopper_pearson_n",
    "decision",
    "decision_confidence",
    "doubling_looks",
    "draw_measures",
    "expected_entropy",
    "frame_measures",
    "massart",
    "massart_n",
    "mutual_information",
    "mutual_information_se",
    "predictive_entropy",
    "predictive_probs",
    "sample_decisions",
    "sequential_scheme",
    "simulate_sprt",
    "sprt",
    "sprt_cap",
    "steering_moments",
    "within_ball",
    "wilson",
    "ClaimResult",
    "Comparison",
    "Finding",
    "MethodClaim",
    "Reason",
    "Verdict",
    "decide_claim",
    "decide_claims",
    "decide_finding",
    "decide_findings",
    "mean_verdicts",
    "sign_runs_needed",
    "mean_interval",
    "MeanInterval",
    "ScoreClaim",
    "share_interval",
    "split_gamma",
    "PairedTable",
    "PairedTest",
    "difference_interval",
    "mcnemar_p",
    "paired_table",
    "paired_test",
    "ReplicateInterval",
    "replicate_bounded_interval",
    "replicate_t_interval",
]
