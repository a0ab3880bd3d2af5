"""The certify gate's ledger: attempts per policy name, replayed when unchanged, otherwise the next attempt on a
block of seeds no earlier attempt used, spending γ_k = 6γ/(π²k²); a bad file refused and left as it was. And the
overall error under an adversary who resubmits changed policies, driven through the ledger and computed exactly by
the independent forward recursion of tests/test_uq_threshold.py: ≤ γ."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from test_uq_threshold import decisions, forward

from uqdrive.safety.certify_ledger import SEED_BLOCK, Ledger
from uqdrive.schema import ConfigError
from uqdrive.uq import ThresholdTest
from uqdrive.uq.gate import looks_for


def test_an_unchanged_policy_replays_its_attempt_and_a_changed_one_gets_fresh_seeds(tmp_path):
    ledger = Ledger(tmp_path / "ledger.json")
    first = ledger.attempt("agent.zip", "id-a", "digest-a", 0.05)
    assert (first.number, first.seed_base) == (1, 0) and first.gamma == pytest.approx(6 * 0.05 / math.pi**2)
    assert ledger.attempt("agent.zip", "id-a", "digest-a", 0.05) == first  # replayed: same seeds, same γ_1
    ledger.decided("agent.zip", first, "refuted")
    again = Ledger(tmp_path / "ledger.json")  # as the next CI job reads it
    second = again.attempt("agent.zip", "id-b", "digest-b", 0.05)
    assert second.number == 2 and second.gamma == pytest.approx(first.gamma / 4)
    assert again.attempt("agent.zip", "id-a", "digest-a", 0.05).verdict == "refuted"  # the old attempt, as it was
    fresh = again.attempt("agent.zip", "id-a", "digest-a", 0.05, fresh=True)
    assert fresh.number == 3 and fresh.gamma == pytest.approx(first.gamma / 9)
    other = again.attempt("other.zip", "id-a", "digest-a", 0.05)
    assert other.number == 1  # attempts count per policy name
    saved = json.loads((tmp_path / "ledger.json").read_text())
    assert [a["number"] for a in saved["policies"]["agent.zip"]] == [1, 2, 3] and saved["rule"].startswith("gamma_k")


def test_seed_blocks_never_overlap_whatever_base_seed_each_attempt_asks_for(tmp_path):
    ledger = Ledger(tmp_path / "ledger.json")
    bases = [0, 5, 1_000_003, 0, 2_999_999, 40]
    starts = [ledger.attempt("p", f"id-{i}", f"d-{i}", 0.05, base).seed_base for i, base in enumerate(bases)]
    assert starts[0] == 0 and starts[-1] >= 0
    blocks = sorted(starts)
    assert all(b - a >= SEED_BLOCK for a, b in zip(blocks, blocks[1:]))


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("{broken", "Expecting property name"),
        ('{"format": "dvc.lock"}', "not a 'uqdrive certify ledger' file"),
        ("[1, 2]", "its 'format' is 'list'"),
        ('{"format": "uqdrive certify ledger", "version": 9, "policies": {}}', "version 9, this uqdrive reads 1"),
        ('{"format": "uqdrive certify ledger", "version": 1, "policies": {"p": [{"x": 1}]}}', "unexpected keyword"),
    ],
)
def test_a_bad_ledger_is_one_line_and_left_as_it_is(tmp_path, text, says):
    path = tmp_path / "ledger.json"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        Ledger(path)
    assert str(err.value).startswith(f"ledger {path}: ") and says in str(err.value) and "\n" not in str(err.value)
    assert path.read_text() == text


def test_an_adversary_resubmitting_changed_policies_certifies_one_below_target_with_probability_at_most_gamma(tmp_path):
    """Each resubmission is a changed policy at η1 = η (the worst below-target rate: P(certified) rises with η1 and
    the guarantee covers η1 < η, so its supremum is the value at η). Its attempt's seeds are unused by any earlier
    one, so given the history its chance to certify is that attempt's exact error e_k at γ_k, whatever the adversary
    learnt; P(some attempt certifies) ≤ 1 − Π(1 − e_k) over 10 attempts, plus Σ_{k>10} γ_k for all later ones."""
    gamma, eta = 0.05, 0.9
    ledger = Ledger(tmp_path / "ledger.json")
    survive, spent = 1.0, 0.0
    for k in range(1, 11):
        attempt = ledger.attempt("tuned.zip", f"id-{k}", f"digest-{k}", gamma)
        test = ThresholdTest(eta, attempt.gamma, looks_for(4, 400), forced=False)
        error = float(forward(decisions(test), np.array([eta]))[0][0])
        assert error <= attempt.gamma
        survive, spent = survive * (1 - error), spent + attempt.gamma
    later = gamma - spent  # Σ_{k>10} γ_k = γ − Σ_{k≤10} γ_k, each later attempt's error ≤ its γ_k
    assert 0 < later and 1 - survive + later <= gamma


def test_a_submission_its_check_refuses_spends_no_attempt(tmp_path):
    """The floor is checked at the attempt's own γ_k before the attempt is written."""
    ledger = Ledger(tmp_path / "ledger.json")
    ledger.attempt("p", "id-1", "d-1", 0.05)

    def refuse(gamma: float) -> None:
        raise ConfigError(f"budget too small at gamma={gamma:.4g}")

    with pytest.raises(ConfigError, match="gamma=0.007599"):  # what attempt 2 would have spent
        ledger.attempt("p", "id-2", "d-2", 0.05, check=refuse)
    assert [a.number for a in Ledger(tmp_path / "ledger.json").names["p"]] == [1]
    assert ledger.attempt("p", "id-2", "d-2", 0.05).number == 2
