"""Classification and uncertainty metrics (uqdrive.models.metrics) against values worked out by hand."""

import math

import pytest
import torch

from uqdrive.models.metrics import ECE_BINS, PROB_FLOOR, classification_metrics, mistake_auroc, reliability_bins

# Five frames, three classes. Predicted classes 0, 1, 2, 0, 0 against labels 0, 2, 2, 1, 0: frames 1, 3, 5 right.
# Confidences 0.7, 0.5, 0.85, 0.68, 0.9 sit inside the 15 bins (x15: 10.5, 7.5, 12.75, 10.2, 13.5), and
# frames 1 and 4 share bin 10, so the ECE differs from the mean per-frame gap.
PROBS = torch.tensor(
    [[0.70, 0.20, 0.10], [0.20, 0.50, 0.30], [0.10, 0.05, 0.85], [0.68, 0.22, 0.10], [0.90, 0.05, 0.05]]
)
LABELS = torch.tensor([0, 2, 2, 1, 0])


def test_classification_metrics_match_hand_computed_values():
    m = classification_metrics(PROBS, LABELS)
    assert set(m) == {"accuracy", "nll", "ece", "brier"}  # train logs them as val_<name>
    # micro accuracy 3/5; the macro mean of per-class recalls (1, 0, 1/2) would be 0.5
    assert m["accuracy"] == pytest.approx(0.6)
    nll = -(math.log(0.7) + math.log(0.3) + math.log(0.85) + math.log(0.22) + math.log(0.9)) / 5
    assert m["nll"] == pytest.approx(nll)
    assert m["nll"] == pytest.approx(0.668531, abs=1e-6)
    # bin 10: frames 1, 4 → |mean conf 0.69 − acc 0.5| · 2/5;
    # bins 7, 12, 13: |0.5 − 0|, |0.85 − 1|, |0.9 − 1|, each · 1/5
    assert m["ece"] == pytest.approx(0.19 * 2 / 5 + (0.5 + 0.15 + 0.1) / 5)
    assert m["ece"] == pytest.approx(0.226, abs=1e-6)
    # per frame Σ_c (p_c − y_c)²: 0.14, 0.78, 0.035, 1.0808, 0.015
    assert m["brier"] == pytest.approx((0.14 + 0.78 + 0.035 + 1.0808 + 0.015) / 5)


def test_perfect_and_uniform_predictions():
    labels = torch.tensor([0, 1, 2, 1])
    perfect = classification_metrics(torch.nn.functional.one_hot(labels, 3).float(), labels)
    assert perfect == pytest.approx({"accuracy": 1.0, "nll": 0.0, "ece": 0.0, "brier": 0.0}, abs=1e-9)
    uniform = classification_metrics(torch.full((4, 3), 1 / 3), labels)
    assert uniform["nll"] == pytest.approx(math.log(3))
    assert uniform["brier"] == pytest.approx((2 / 3) ** 2 + 2 * (1 / 3) ** 2)


def test_nll_of_a_zero_probability_is_capped_not_infinite():
    m = classification_metrics(torch.tensor([[1.0, 0.0], [1.0, 0.0]]), torch.tensor([1, 0]))
    assert m["nll"] == pytest.approx(-math.log(PROB_FLOOR) / 2)


def test_mistake_auroc_ranks_wrong_frames_by_uncertainty():
    wrong = torch.tensor([0, 0, 1, 1])
    assert mistake_auroc(torch.tensor([0.1, 0.2, 0.6, 0.9]), wrong) == pytest.approx(1.0)  # flags every mistake
    assert mistake_auroc(torch.tensor([0.9, 0.6, 0.2, 0.1]), wrong) == pytest.approx(0.0)
    assert mistake_auroc(torch.tensor([0.5, 0.5, 0.5, 0.5]), wrong) == pytest.approx(0.5)  # ties count half
    # pairs (wrong, right): 0.35 > 0.1, 0.35 < 0.4, 0.8 > both → 3 of 4
    assert mistake_auroc(torch.tensor([0.1, 0.4, 0.35, 0.8]), wrong) == pytest.approx(0.75)
    # scores in nats beyond [0, 1] (mutual information) rank the same
    assert mistake_auroc(torch.tensor([1.0, 4.0, 3.5, 8.0]), wrong) == pytest.approx(0.75)


def test_mistake_auroc_is_nan_without_both_kinds_of_frame():
    assert math.isnan(mistake_auroc(torch.tensor([0.1, 0.9]), torch.tensor([0, 0])))
    assert math.isnan(mistake_auroc(torch.tensor([0.1, 0.9]), torch.tensor([1, 1])))


def test_reliability_bins_are_the_ones_the_ece_averages():
    bins = reliability_bins(PROBS, LABELS)
    filled = torch.nonzero(bins["frames"]).flatten().tolist()
    assert filled == [7, 10, 12, 13] and len(bins["frames"]) == ECE_BINS
    assert bins["confidence"][10] == pytest.approx(0.69) and bins["accuracy"][10] == pytest.approx(0.5)
    assert torch.isnan(bins["accuracy"][0])

    generator = torch.Generator().manual_seed(0)
    probs = torch.softmax(3 * torch.randn(2000, 21, generator=generator, dtype=torch.float64), 1)
    labels = torch.randint(0, 21, (2000,), generator=generator)
    labels[:1200] = probs[:1200].argmax(1)
    bins = reliability_bins(probs, labels)
    gap = torch.nansum(bins["frames"] / 2000 * (bins["accuracy"] - bins["confidence"]).abs())
    assert float(gap) == pytest.approx(classification_metrics(probs, labels)["ece"], abs=1e-6)
