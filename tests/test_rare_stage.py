"""The `rare` stage on the tiny profile with random-weight controllers (which leave the road): η1 ≥ target over the
domain refuted within one round and certified false, the record and its failure records, the MLflow run, every
rollout replayed on a rerun, and bad input in one line before any rollout."""

import json

import pytest
from conftest import ALL_TENTHS
from mlflow.tracking import MlflowClient

import uqdrive.safety.runner as runner
from uqdrive.pipeline.rare_stage import run_rare
from uqdrive.records import as_dict
from uqdrive.schema import ConfigError
from uqdrive.tracking import store_uris

TINY = ("rare.refute_budget=8", "rare.round_size=4", "rare.target=0.9", "rare.certify_budget=40", "rare.certify=true")


@pytest.fixture
def rare_config(stage_config, random_models):
    def make(*overrides: str):
        folder = random_models["mcd"].parent
        model = f"envelope.model_path={folder}/${{model.name}}.pt"
        shapes = () if any(o.startswith("rare.shapes=") for o in overrides) else ("rare.shapes={noise:[2.0,5.0]}",)
        return stage_config("rare", model, *ALL_TENTHS, *shapes, *TINY, *overrides)

    return make


class Replaying:
    """An executor that must not run a rollout (every one is in its cell's log)."""

    @staticmethod
    def run(*args, **kwargs):
        raise AssertionError("rollouts started")

    def close(self) -> None:
        pass


def flat(run) -> dict:
    return {**json.loads(json.dumps(as_dict(run.result))), "reused": run.reused}


@pytest.mark.slow
def test_the_stage_refutes_certifies_logs_and_a_rerun_replays_every_rollout(rare_config, tmp_path, monkeypatch):
    record = flat(run_rare(rare_config("model=vi")))
    assert record["refuted"] and record["refute_rollouts"] <= 4 and not record["reused"]
    assert record["certified"] == "below" and record["certify_rollouts"] == 35  # ceil(1.2 × 29): the first look
    assert record["domain"]["noise"] == [0.0, 0.2, 2.0, 5.0] and record["domain"]["weather.blend"][2:] == [1.0, 1.0]
    assert record["failures"] == len(record["failure_records"]) >= 1 and record["lower_bound"] > 0.1
    estimate, weights = record["estimate"], [r["weight"] for r in record["failure_records"]]
    assert estimate["estimate"] == pytest.approx(sum(weights) / record["refute_rollouts"])  # mean of w·1{fail}
    assert estimate["interval"][0] <= estimate["estimate"] <= estimate["interval"][1]
    assert (estimate["if_dominant"] is None) == (max(weights) > 1)
    first = record["failure_records"][0]
    assert set(first) == {"seed", "noise", "weather.blend", "weight"} and 0 <= first["noise"] <= 0.2
    saved = json.loads((tmp_path / "metrics/rare/vi-seed0.json").read_text())
    assert saved == {k: v for k, v in record.items() if k != "reused"}
    client = MlflowClient(store_uris(tmp_path)[0])
    (run,) = client.search_runs([client.get_experiment_by_name("uqdrive/rare").experiment_id])
    assert run.data.metrics["refuted"] == 1 and run.data.metrics["certified"] == -1

    monkeypatch.setattr(runner, "make_executor", lambda *a, **k: Replaying())
    again = flat(run_rare(rare_config("model=vi")))
    assert again["reused"] and {**again, "seconds": 0, "reused": 0} == {**record, "seconds": 0, "reused": 0}


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("rare.defensive=0.0", "rare.defensive=0.0: input should be greater than 0"),
        ("rare.certify_budget=4", "rare.certify_budget=4 cannot certify eta1 >= 0.9 at gamma=0.05 even with zero"),
        ("rare.shapes={fog:[1.0,2.0]}", "rare.shapes.fog: not an axis of envelope.axes ['noise', 'weather.blend']"),
    ],
)
def test_bad_input_is_one_line_before_any_rollout(rare_config, monkeypatch, override, message):
    monkeypatch.setattr(runner, "make_executor", lambda *a, **k: Replaying())
    with pytest.raises(ConfigError) as err:
        run_rare(rare_config("model=vi", override))
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


@pytest.mark.slow
def test_in_a_gym_world_the_domain_over_its_crash_rate_is_refuted_and_certified_as_its_known_mean(
    stage_config, random_models
):
    """The coin env fails each run with its crash rate, whatever drives: with the rate ~ Beta(1, 9) on [0, 1] the
    failure probability over the domain is exactly 0.1, so η1 ≥ 0.99 is false (refuted, the bound below 0.1) and
    η1 ≥ 0.5 true (certified)."""
    from test_gym_stages import COIN, COIN_RATE, RATE_AXES

    model = f"envelope.model_path={random_models['mcd'].parent}/${{model.name}}.pt"
    domain = (*COIN, COIN_RATE, RATE_AXES, "rare.shapes={gym_world.env_kwargs.rate:[1.0,9.0]}", "executor.workers=1")
    budgets = ("rare.refute_budget=200", "rare.round_size=20")
    false_claim = flat(run_rare(stage_config("rare", model, *ALL_TENTHS, *domain, *budgets, "rare.target=0.99")))
    assert false_claim["refuted"] and 0 < false_claim["lower_bound"] <= 0.1
    certify = ("rare.target=0.5", "rare.certify=true", "rare.certify_budget=100")
    true_claim = flat(run_rare(stage_config("rare", model, *ALL_TENTHS, *domain, *budgets, *certify)))
    assert not true_claim["refuted"] and true_claim["certified"] == "above"
