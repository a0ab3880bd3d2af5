"""Agreement of a predictive with a reference (HMC) on synthetic inputs whose answers are known."""

import pytest
import torch

from uqdrive.models.agreement import agreement_with_reference


def test_identical_predictives_agree_perfectly():
    g = torch.Generator().manual_seed(0)
    probs = torch.softmax(torch.randn((50, 4), generator=g), -1)
    mi = torch.rand(50, generator=g)
    a = agreement_with_reference(probs, mi, probs, mi)
    assert a == {"tv_distance": 0.0, "tv_distance_max": 0.0, "argmax_agreement": 1.0, "mi_spearman": pytest.approx(1.0)}


def test_known_distances_decisions_and_ranks():
    probs = torch.tensor([[1.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.2, 0.2, 0.6]])
    ref = torch.tensor([[0.0, 1.0, 0.0], [0.5, 0.25, 0.25], [0.2, 0.2, 0.6]])
    a = agreement_with_reference(probs, torch.tensor([0.1, 0.2, 0.3]), ref, torch.tensor([3.0, 2.0, 1.0]))
    assert a["tv_distance"] == pytest.approx((1.0 + 0.25 + 0.0) / 3) and a["tv_distance_max"] == pytest.approx(1.0)
    assert a["argmax_agreement"] == pytest.approx(2 / 3)  # frame 0 decides differently; frame 1 ties break to class 0
    assert a["mi_spearman"] == pytest.approx(-1.0)  # the reverse ranking


def test_constant_mi_has_no_rank_correlation_and_shapes_must_match():
    probs = torch.full((4, 2), 0.5)
    assert agreement_with_reference(probs, torch.zeros(4), probs, torch.arange(4.0))["mi_spearman"] is None
    with pytest.raises(ValueError, match="matching shapes"):
        agreement_with_reference(probs, torch.zeros(4), probs[:3], torch.zeros(3))
