"""Per-frame measures on hand-made posterior samples, and rejection of bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from uqdrive.uq import (
    decision,
    decision_confidence,
    draw_measures,
    expected_entropy,
    frame_measures,
    mutual_information,
    mutual_information_se,
    predictive_entropy,
    sample_decisions,
    steering_moments,
    within_ball,
)

CENTRES = torch.tensor([-0.2, -0.1, 0.0, 0.1, 0.2], dtype=torch.float64)


def peaked(classes: list[list[int]]) -> torch.Tensor:
    """[n, B, 5] samples: 0.6 on the given class, 0.1 on each other class."""
    idx = torch.tensor(classes)
    return torch.full((*idx.shape, 5), 0.1, dtype=torch.float64).scatter(-1, idx[..., None], 0.6)


# Frame 0: samples pick classes 2, 2, 3, 0 -> predictive mass 0.35 on class 2, so pi = 0.0;
#   sample decisions 0.0, 0.0, 0.1, -0.2.
# Frame 1: samples pick classes 4, 4, 4, 1 -> pi = 0.2; sample decisions 0.2, 0.2, 0.2, -0.1.
PROBS = peaked([[2, 4], [2, 4], [3, 4], [0, 1]])
UNNORMALISED = PROBS.clone()
UNNORMALISED[2, 1] *= 0.9


def test_decisions_by_hand() -> None:
    assert decision(PROBS, CENTRES).tolist() == pytest.approx([0.0, 0.2])
    assert sample_decisions(PROBS, CENTRES)[:, 0].tolist() == pytest.approx([0.0, 0.0, 0.1, -0.2])


@pytest.mark.parametrize(
    ("eps", "expected"),
    [
        (0.05, [0.50, 0.75]),  # only exact matches: 2/4 and 3/4
        (0.10, [0.75, 0.75]),  # frame 0 gains the 0.1 sample (edge of the closed ball)
        (0.25, [1.00, 0.75]),  # frame 1's -0.1 is 0.3 away
        (0.30, [1.00, 1.00]),  # ... and is inside at exactly eps = 0.3
    ],
)
def test_eta2_by_hand(eps: float, expected: list[float]) -> None:
    assert decision_confidence(PROBS, CENTRES, eps).tolist() == pytest.approx(expected)


def test_eta2_with_given_pi_and_numpy_input() -> None:
    eta2 = decision_confidence(PROBS.numpy(), CENTRES.numpy(), 0.05, pi=np.array([0.1, -0.1]))
    assert eta2.tolist() == pytest.approx([0.25, 0.25])


def test_mutual_information_of_identical_samples_is_zero() -> None:
    p = torch.distributions.Dirichlet(torch.ones(21, dtype=torch.float64)).sample((3,))
    probs = p[None].expand(8, 3, 21)
    assert mutual_information(probs).tolist() == pytest.approx([0.0] * 3, abs=1e-12)
    assert predictive_entropy(probs).tolist() == pytest.approx(expected_entropy(probs).tolist())


def test_mutual_information_of_disagreeing_confident_halves_is_ln2() -> None:
    probs = torch.zeros(6, 1, 5, dtype=torch.float64)
    probs[:3, 0, 0] = 1.0
    probs[3:, 0, 3] = 1.0
    assert mutual_information(probs).item() == pytest.approx(math.log(2))
    assert predictive_entropy(probs).item() == pytest.approx(math.log(2))
    assert expected_entropy(probs).item() == pytest.approx(0.0)


def test_steering_moments_under_the_predictive() -> None:
    probs = torch.zeros(2, 1, 5, dtype=torch.float64)
    probs[0, 0, 1] = 1.0  # -0.1
    probs[1, 0, 3] = 1.0  # +0.1
    mean, var = steering_moments(probs, CENTRES)
    assert mean.item() == pytest.approx(0.0)
    assert var.item() == pytest.approx(0.01)


def test_frame_measures_agree_with_the_single_functions() -> None:
    m = frame_measures(PROBS, CENTRES, 0.1)
    assert torch.equal(m.decision, decision(PROBS, CENTRES))
    assert torch.equal(m.eta2, decision_confidence(PROBS, CENTRES, 0.1))
    assert torch.allclose(m.mutual_information, mutual_information(PROBS))
    assert torch.allclose(m.entropy, predictive_entropy(PROBS))
    mean, var = steering_moments(PROBS, CENTRES)
    assert torch.allclose(m.steering_mean, mean) and torch.allclose(m.steering_var, var)


def test_split_draws_give_the_mode_from_the_first_and_eta2_from_the_others_exactly() -> None:
    probs = torch.distributions.Dirichlet(torch.full((5,), 0.3)).sample((60, 3))
    whole = frame_measures(probs, CENTRES.float(), 0.1, split=25)
    first = frame_measures(probs[:25], CENTRES.float(), 0.1)
    for field in ("decision", "mutual_information", "entropy", "steering_mean", "steering_var"):
        assert torch.equal(getattr(whole, field), getattr(first, field)), field
    assert torch.equal(whole.eta2, decision_confidence(probs[25:], CENTRES.float(), 0.1, first.decision))
    for split in (0, 60, -1):
        with pytest.raises(ValueError, match=f"split={split} must leave draws on both sides"):
            frame_measures(probs, CENTRES.float(), 0.1, split=split)


def _with(value: float, at: tuple[int, int, int]) -> torch.Tensor:
    probs = PROBS.clone()
    probs[at] = value
    return probs


@pytest.mark.parametrize(
    ("probs", "match"),
    [
        (_with(math.nan, (1, 0, 2)), "probs must be finite, got NaN or inf"),
        (_with(math.inf, (3, 1, 0)), "probs must be finite, got NaN or inf"),
        (_with(-math.inf, (0, 0, 4)), "probs must be finite, got NaN or inf"),
        (_with(-0.1, (2, 1, 3)), r"probs must be >= 0, got minimum -0\.1"),
        (_with(0.7, (0, 0, 0)), r"probs must sum to 1 along C .*got sum 1\.6 at sample 0, frame 0"),
    ],
)
def test_every_non_probability_is_rejected_by_its_check(probs: torch.Tensor, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        frame_measures(probs, CENTRES, 0.1)


@pytest.mark.parametrize(
    ("probs", "centres", "eps", "match"),
    [
        (PROBS[0], CENTRES, 0.1, r"probs must have shape \[n, B, C\] \(3-D\), got shape \(2, 5\)"),
        (PROBS[None], CENTRES, 0.1, r"3-D\), got shape \(1, 4, 2, 5\)"),
        (UNNORMALISED, CENTRES, 0.1, r"probs must sum to 1 along C .*got sum 0\.9 at sample 2, frame 1"),
        (PROBS, CENTRES[:4], 0.1, r"centres must be 1-D with length C=5 .*got shape \(4,\)"),
        (PROBS, CENTRES, 0.0, r"eps must be a finite number > 0 .*got 0\.0"),
        (PROBS, CENTRES, -0.1, r"eps must be .*got -0\.1"),
        (PROBS, CENTRES, float("nan"), r"eps must be .*got nan"),
    ],
)
def test_bad_input_is_rejected_with_a_clear_message(probs, centres, eps, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        frame_measures(probs, centres, eps)
    if "eps" not in match:
        with pytest.raises(ValueError, match=match):
            decision(probs, centres)


def test_small_rounding_in_probabilities_is_accepted() -> None:
    assert decision_confidence(PROBS * (1 + 5e-5), CENTRES, 0.1).shape == (2,)


def test_mutual_information_se_is_the_jackknife_of_the_plug_in_estimate() -> None:
    """Leave each draw out in turn, by a plain loop over the single-function MI."""
    probs = torch.softmax(torch.randn((9, 3, 5), generator=torch.Generator().manual_seed(4)), -1).double()
    n = len(probs)
    left_out = torch.stack([mutual_information(torch.cat([probs[:i], probs[i + 1 :]])) for i in range(n)])
    expected = ((n - 1) / n * ((left_out - left_out.mean(0)) ** 2).sum(0)).sqrt()
    assert torch.allclose(mutual_information_se(probs), expected, atol=1e-12)
    assert torch.equal(mutual_information_se(probs[:1, :1].expand(4, 1, 5)), torch.zeros(1, dtype=probs.dtype))
    assert torch.isnan(mutual_information_se(probs[:1])).all()


def test_within_ball_counts_what_eta2_counts_in_numpy_and_torch() -> None:
    probs = peaked([[0, 2], [1, 2], [4, 2]])
    pi = torch.tensor([-0.2, 0.0])
    inside = within_ball(CENTRES[probs.argmax(-1)], pi, 0.1)
    assert inside.tolist() == [[True, True], [True, True], [False, True]]
    assert torch.equal(inside.double().mean(0), decision_confidence(probs, CENTRES, 0.1, pi))
    assert within_ball(CENTRES.numpy()[probs.numpy().argmax(-1)], pi.numpy(), 0.1).tolist() == inside.tolist()


@pytest.mark.parametrize("n", [1, 2, 30])
def test_draw_measures_in_numpy_are_those_of_frame_measures(n: int) -> None:
    probs = torch.softmax(3 * torch.randn((n, 1, 5), generator=torch.Generator().manual_seed(n)), -1).double()
    m = frame_measures(probs, CENTRES, 0.1)
    mi, se, entropy = draw_measures(probs[:, 0].numpy())
    assert mi == pytest.approx(float(m.mutual_information[0]), abs=1e-12)
    assert entropy == pytest.approx(float(m.entropy[0]), abs=1e-12)
    assert (math.isnan(se) and n == 1) or se == pytest.approx(float(m.mutual_information_se[0]), abs=1e-12)
    with pytest.raises(ValueError, match="sum to 1"):
        draw_measures(probs[:, 0].numpy() * 0.5)
