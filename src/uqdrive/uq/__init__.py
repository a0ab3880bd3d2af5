"""Uncertainty quantification: per-frame measures, Bernoulli-rate estimators with (θ, γ) guarantees and
sequential threshold tests with exact error.

Knows nothing of the simulator, data or models: it takes posterior class probabilities
``[n, B, C]`` and the class centres, or 0/1 outcomes.
Comparisons of cells on the same seeds: exact paired tests (`paired`), Bonferroni (`multiplicity`),
intervals over training replicates (`replicates`, `betting`); the two levels of answer: a family of findings for
these trained controllers (`family`) and method claims over training runs (`claims`), with their `verdict`;
Learn-then-Test (`ltt`); rare events over an operating domain — refutation by importance sampling with a bound valid
at any stopping time, certification at the zero-failure floor (`rare`, `rare_proposal`).
"""

from uqdrive.uq.betting import MeanInterval, mean_interval
from uqdrive.uq.bounds import (
    chernoff_n,
    clopper_pearson_interval,
    clopper_pearson_n,
    massart_n,
)
from uqdrive.uq.claims import (
    ClaimResult,
    MethodClaim,
    ScoreClaim,
    decide_claim,
    decide_claims,
    mean_verdicts,
    sign_runs_needed,
)
from uqdrive.uq.estimators import (
    Estimate,
    SPRTResult,
    chernoff,
    clopper_pearson,
    massart,
    sequential,
    simulate_sprt,
    sprt,
    sprt_cap,
    wilson,
)
from uqdrive.uq.family import Comparison, Finding, decide_finding, decide_findings
from uqdrive.uq.measures import (
    FrameMeasures,
    check_samples,
    decision,
    decision_confidence,
    draw_measures,
    expected_entropy,
    frame_measures,
    mutual_information,
    mutual_information_se,
    predictive_entropy,
    predictive_probs,
    sample_decisions,
    steering_moments,
    within_ball,
)
from uqdrive.uq.multiplicity import split_gamma
from uqdrive.uq.paired import (
    PairedTable,
    PairedTest,
    difference_interval,
    mcnemar_p,
    paired_table,
    paired_test,
    share_interval,
)
from uqdrive.uq.replicates import ReplicateInterval, replicate_bounded_interval, replicate_t_interval
from uqdrive.uq.sequential import SequentialScheme, sequential_scheme
from uqdrive.uq.threshold import ThresholdDecision, ThresholdTest, doubling_looks
from uqdrive.uq.verdict import Reason, Verdict

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
    "sequential",
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
