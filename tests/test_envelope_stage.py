"""The `envelope` stage on the tiny profile (8 search rollouts, 4 regions, 16 certification rollouts in all) with
random-weight controllers: the map and its files, the MLflow run, rollouts replayed on a rerun, any axes by override,
and one-line errors before any rollout."""

import json
from fractions import Fraction

import pytest
from conftest import ALL_TENTHS
from mlflow.tracking import MlflowClient

import uqdrive.safety.runner as runner
from uqdrive.envelope.map_records import EnvelopeResult
from uqdrive.pipeline.envelope_stage import run_envelope
from uqdrive.records import as_dict, read_record
from uqdrive.schema import ConfigError
from uqdrive.tracking import store_uris


@pytest.fixture
def envelope_config(stage_config, random_models):
    def make(*overrides: str):
        folder = random_models["mcd"].parent
        return stage_config("envelope", f"envelope.model_path={folder}/${{model.name}}.pt", *ALL_TENTHS, *overrides)

    return make


def no_rollouts(*args, **kwargs):
    raise AssertionError("rollouts started")


class Replaying:
    """An executor that must not run a rollout (every one is in its cell's log)."""

    run = staticmethod(no_rollouts)

    def close(self) -> None:
        pass


def flat(run) -> dict:
    """The map's record as its file holds it, plus ``reused``."""
    return {**json.loads(json.dumps(as_dict(run.result))), "reused": run.reused}


@pytest.mark.slow
def test_the_stage_writes_its_map_logs_a_run_and_a_rerun_replays_every_rollout(envelope_config, tmp_path, monkeypatch):
    record = flat(run_envelope(envelope_config("model=vi")))
    saved = json.loads((tmp_path / "metrics/envelope/vi-seed0.json").read_text())
    assert saved == {k: v for k, v in record.items() if k != "reused"} and not record["reused"]
    assert record["axes"] == [{"key": "noise", "range": [0.0, 0.2]}, {"key": "weather.blend", "range": [0.0, 1.0]}]
    assert record["blend"] == {"from": "clear_noon", "to": "rain"} and record["threshold"] == 0.9
    regions = record["regions"]
    assert len(regions) == 4 and sum(r["volume"] for r in regions) == 1.0
    assert sum(map(Fraction, (r["gamma"] for r in regions))) <= Fraction(0.05)
    assert {r["name"] for r in regions} == {"r0", "r1", "r2", "r3"}
    assert regions[1]["bounds"] == {"noise": [0.1, 0.2], "weather.blend": [0.0, 0.5]}  # child 1: upper half of axis 0
    assert sorted(r["order"] for r in regions) == [0, 1, 2, 3]
    for r in regions:  # a random-weight controller leaves the road: 4 rollouts certify each region unsafe
        assert (r["verdict"], r["rollouts"], r["undecided_by"]) == ("unsafe", 4, None), r
    search = record["search"]
    assert len(search["points"]) == 8 == search["rollouts"] == len(search["outcomes"]) and search["rounds"] == [4, 4]
    assert all(0 <= noise <= 0.2 and 0 <= t <= 1 for noise, t in search["points"])
    assert search["failures"] == search["outcomes"].count("0")
    assert (
        read_record(EnvelopeResult, tmp_path / "metrics/envelope/vi-seed0.json", "envelope@vi").regions[1].name == "r1"
    )
    assert record["rollouts"]["certify"] == sum(r["rollouts"] for r in regions)
    assert record["rollouts"]["unread"] == 0  # every test decided at its first look: nothing was run ahead of it
    assert record["rollouts"]["total"] == 8 + record["rollouts"]["certify"]
    assert record["grid"]["cells"] == 4 and record["grid"]["rollouts"] == 4 * record["grid"]["per_cell"]
    plots = tmp_path / "plots/envelope/vi-seed0"
    assert (plots / "map.png").stat().st_size > 5000
    assert len((plots / "regions.csv").read_text().splitlines()) == 5
    assert len((plots / "search.csv").read_text().splitlines()) == 9

    client = MlflowClient(store_uris(tmp_path)[0])
    (run,) = client.search_runs([client.get_experiment_by_name("uqdrive/envelope").experiment_id])
    assert run.data.params["method"] == "vi" and run.data.params["envelope.certify_budget"] == "16"
    assert run.data.metrics["total_rollouts"] == record["rollouts"]["total"]
    assert {a.path for a in client.list_artifacts(run.info.run_id)} == {
        "vi-seed0.json",
        "map.png",
        "regions.csv",
        "search.csv",
    }

    monkeypatch.setattr(runner, "make_executor", lambda *a, **k: Replaying())  # every round and region replays its log
    again = flat(run_envelope(envelope_config("model=vi", "executor.workers=2")))
    assert again["reused"] and {**again, "seconds": 0, "reused": 0} == {**record, "seconds": 0, "reused": 0}


@pytest.mark.slow
def test_any_numbers_of_the_world_are_axes(envelope_config):
    axes = (
        "[{key:scenario.ring_radius,range:[10,24]},{key:noise,range:[0,0.2]},{key:weather.fog_density,range:[0,0.05]}]"
    )
    record = flat(run_envelope(envelope_config("model=mcd", f"envelope.axes={axes}", "envelope.region_budget=64")))
    assert [a["key"] for a in record["axes"]] == ["scenario.ring_radius", "noise", "weather.fog_density"]
    assert record["blend"] is None and len(record["regions"]) == 8  # three axes halved once
    assert {tuple(r["bounds"]["scenario.ring_radius"]) for r in record["regions"]} == {(10.0, 17.0), (17.0, 24.0)}
    by = sorted((r["order"], r["verdict"], r["rollouts"], r["undecided_by"]) for r in record["regions"])
    assert by == [(i, "unsafe", 4, None) for i in range(4)] + [
        (i, "undecided", 0, "certify_budget") for i in range(4, 8)
    ]


@pytest.mark.parametrize(
    ("override", "message"),
    [
        (
            "envelope.axes=[{key:noise,range:[0,0.2]}]",
            "envelope.axes=[{'key': 'noise', 'range': [0, 0.2]}]: tuple should have at least 2",
        ),
        (
            "envelope.axes=[{key:weather.shadow,range:[0,1]},{key:noise,range:[0,0.2]}]",
            "envelope.axes[0].key='weather.shadow' must be noise, weather.blend, a number of scenario or weather",
        ),
        (
            "envelope.axes=[{key:scenario.ring_radius,range:[2,24]},{key:noise,range:[0,0.2]}]",
            "envelope.axes: the condition scenario.ring_radius=2, noise=0 is not a valid world: scenario.ring_width",
        ),
        (
            "envelope.blend.from=snow",
            "envelope.blend.from='snow' is not loaded; choose one of ['afternoon', 'clear_noon'",
        ),
        ("envelope.threshold=1.0", "envelope.threshold=1.0: input should be less than 1"),
        ("envelope.search.initial=20", "envelope.search.initial=20 must be <= budget (8)"),
        ("envelope.region_budget=2", "envelope.region_budget=2 must be >= look_size (4)"),
        (
            "envelope.region_budget=44",
            "envelope.region_budget=44 is too small: with up to 4 regions (partition.max_depth=1) no region could be",
        ),
        ("envelope.theta=0.1", "envelope.theta=0.1 must be < min(threshold, 1 - threshold) = 0.1"),
        ("envelope.model_path=/nonexistent/vi.pt", "envelope.model_path=/nonexistent/vi.pt does not exist; train it"),
    ],
)
def test_a_bad_value_is_one_line_before_any_rollout(envelope_config, tmp_path, monkeypatch, override, message):
    monkeypatch.setattr(runner, "make_executor", no_rollouts)
    with pytest.raises(ConfigError) as err:
        run_envelope(envelope_config("model=vi", override))
    assert str(err.value).startswith(message) and "\n" not in str(err.value), str(err.value)
    assert not (tmp_path / "metrics").exists() and not (tmp_path / "mlflow.db").exists()
