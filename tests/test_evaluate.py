"""The heldout configuration and the evaluate stage on the tiny profile, with random-weight models and
synthetic held-out files (the real collection runs in test_dvc_pipeline)."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import ALL_TENTHS
from mlflow.tracking import MlflowClient

from uqdrive.data.frames import encode_png
from uqdrive.data.heldout import heldout_path
from uqdrive.data.tables import RAW_SCHEMA, write_table_batches
from uqdrive.models.heldout_eval import heldout_cell as cell_metrics
from uqdrive.pipeline.evaluate_stage import run_evaluate
from uqdrive.records import as_dict
from uqdrive.tracking import store_uris

METRIC_KEYS = {
    "accuracy",
    "nll",
    "ece",
    "brier",
    "mean_mutual_information",
    "mean_eta2",
    "auroc_mi",
    "auroc_one_minus_eta2",
    "auroc_note",
    "frames",
    "mistakes",
}
AGREEMENT_KEYS = {"hmc_tv_distance", "hmc_tv_distance_max", "hmc_argmax_agreement", "hmc_mi_spearman"}


def write_heldout(
    root,
    weather: str,
    noise: float,
    frames: int = 24,
    seed: int = 0,
    scenario: str = "roundabout",
    name: str | None = None,
):
    """A raw held-out file as the heldout stage names it, with random camera frames: evaluate's plumbing
    needs frames and labels, not a drive."""
    rng = np.random.default_rng(seed)
    steering = rng.uniform(-0.3, 0.3, frames)
    columns = {
        "scenario": [scenario] * frames,
        "weather": [weather] * frames,
        "noise": [noise] * frames,
        "episode": [0] * frames,
        "seed": [200000] * frames,
        "step": list(range(frames)),
        "image": [encode_png(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)) for _ in range(frames)],
        "steering": steering,
        "applied_steering": steering,
        **{k: [0.0] * frames for k in ("t", "x", "y", "yaw", "speed", "lateral_deviation")},
    }
    path = root / "data/heldout" / (name or f"{scenario}-{weather}-noise{noise}.parquet")
    write_table_batches(path, RAW_SCHEMA, [columns])
    return path


@pytest.fixture(scope="module")
def store_root(tmp_path_factory):
    """One MLflow store for the module's stage runs: creating one costs seconds (its schema migrations)."""
    return tmp_path_factory.mktemp("evaluate-store")


def evaluate_config(stage_config, random_models, store_root, out, *overrides: str):
    """The evaluate config on the random models (as replicate 0: models/<method>/seed0.pt), inputs and outputs under
    `out`, MLflow runs in `store_root`."""
    models = out / "models"
    for method, path in random_models.items():
        (models / method).mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, models / method / "seed0.pt")
    return stage_config(
        "evaluate",
        f"paths.root={store_root}",
        f"paths.models={models}",
        *ALL_TENTHS,
        f"paths.metrics={out}/metrics",
        f"paths.plots={out}/plots",
        f"evaluate.heldout_dir={out}/data/heldout",
        *overrides,
    )


def test_heldout_config_writes_what_evaluate_reads(stage_config, tmp_path):
    heldout = stage_config("heldout", "weather=rain", "noise=0.05")
    evaluate = stage_config("evaluate", "weathers=[rain]", "noises=[0.05]")
    assert heldout.scenario.name == evaluate.scenario.name == "roundabout"
    expected = heldout_path(evaluate.evaluate.heldout_dir, evaluate.scenario.name, "rain", 0.05)
    assert Path(heldout.collect.out) == expected == tmp_path / "data/heldout/roundabout-rain-noise0.05.parquet"
    # its metrics JSON, mosaic and MLflow run are named after the condition and kept apart from the training
    # collection's (metrics/collect/roundabout.json): the heldout stage's outputs are folders of their own
    assert heldout.collect.name == "heldout-roundabout-rain-noise0.05"
    assert heldout.collect.metrics == f"{tmp_path}/metrics/heldout/roundabout-rain-noise0.05.json"
    assert heldout.collect.mosaic == f"{tmp_path}/plots/heldout/roundabout-rain-noise0.05_mosaic.png"
    collect = stage_config("collect", "scenario=roundabout").collect
    assert collect.name == "roundabout" and collect.metrics == f"{tmp_path}/metrics/collect/roundabout.json"


def test_heldout_episodes_are_new_seeds_in_every_profile(stage_config):
    for profile in ("tiny", "quick", "paper"):
        train = stage_config("collect", f"profile={profile}").collect
        heldout = stage_config("heldout", f"profile={profile}").collect
        assert heldout.episodes >= 1
        assert set(range(train.base_seed, train.base_seed + train.episodes)).isdisjoint(
            range(heldout.base_seed, heldout.base_seed + heldout.episodes)
        )


def test_outputs_json_plots_and_one_mlflow_run_per_method(stage_config, tmp_path, random_models, store_root):
    for i, (weather, noise) in enumerate([(w, n) for w in ("clear_noon", "rain") for n in (0.0, 0.05)]):
        write_heldout(tmp_path, weather, noise, seed=i)
    result = run_evaluate(
        evaluate_config(
            stage_config,
            random_models,
            store_root,
            tmp_path,
            "methods=[mcd,hmc]",
            "weathers=[clear_noon,rain]",
            "noises=[0.0,0.05]",
        )
    )
    table = json.loads((tmp_path / "metrics/evaluate.json").read_text())["cells"]
    assert table == as_dict(result)["cells"]
    assert {m: {w: sorted(c) for w, c in t.items()} for m, t in table.items()} == {
        m: {"clear_noon": ["noise0.0", "noise0.05"], "rain": ["noise0.0", "noise0.05"]} for m in ("mcd", "hmc")
    }
    cell = table["hmc"]["rain"]["noise0.05"]
    assert set(cell) == METRIC_KEYS | AGREEMENT_KEYS and cell["frames"] == 24
    mcd = table["mcd"]["rain"]["noise0.05"]
    assert set(mcd) == METRIC_KEYS | AGREEMENT_KEYS
    # HMC against its own second draw set is the noise floor: closer than a different (random) model
    assert cell["hmc_tv_distance"] < mcd["hmc_tv_distance"]
    assert 0 <= mcd["hmc_tv_distance"] <= mcd["hmc_tv_distance_max"] <= 1 and -1 <= mcd["hmc_mi_spearman"] <= 1
    assert 0 <= cell["accuracy"] <= 1 and cell["nll"] > 0 and 0 <= cell["ece"] <= 1 and 0 <= cell["brier"] <= 2
    assert 0 < cell["mean_eta2"] <= 1 and cell["mean_mutual_information"] >= 0
    assert cell["mistakes"] == round((1 - cell["accuracy"]) * cell["frames"])

    plots = tmp_path / "plots/evaluate"
    conditions = (plots / "conditions.csv").read_text().splitlines()
    assert conditions[0].startswith("series,method,weather,noise,accuracy") and len(conditions) == 1 + 2 * 4
    reliability = (plots / "reliability.csv").read_text().splitlines()
    assert reliability[0] == "series,method,weather,noise,bin,bin_low,bin_high,confidence,accuracy,frames"
    assert sum(int(line.split(",")[-1]) for line in reliability[1:] if line.startswith("mcd rain noise0.05,")) == 24
    assert sorted(p.name for p in (plots / "figures").iterdir()) == [
        "agreement_hmc.png",
        "conditions.png",
        "reliability_hmc.png",
        "reliability_mcd.png",
    ]

    client = MlflowClient(store_uris(store_root)[0])
    experiment = client.get_experiment_by_name("uqdrive/evaluate")
    runs = {r.data.params["method"]: r for r in client.search_runs([experiment.experiment_id])}
    assert {m: r.info.run_name for m, r in runs.items()} == {"mcd": "adhoc · mcd-seed0", "hmc": "adhoc · hmc-seed0"}
    assert {client.get_experiment(r.info.experiment_id).name for r in runs.values()} == {"uqdrive/evaluate"}
    hmc = runs["hmc"]
    assert hmc.data.params["method"] == "hmc" and hmc.data.params["profile"] == "tiny"
    assert hmc.data.metrics["rain/noise0.05/accuracy"] == pytest.approx(cell["accuracy"])
    assert len([k for k in hmc.data.metrics if k.endswith("/ece")]) == 4
    artifacts = {a.path for a in client.list_artifacts(hmc.info.run_id)}
    assert {
        "reliability_hmc.png",
        "conditions.png",
        "agreement_hmc.png",
        "evaluate.json",
        "conditions.csv",
        "reliability.csv",
    } <= artifacts


def test_a_cell_does_not_change_when_another_condition_is_added(stage_config, tmp_path, random_models, store_root):
    write_heldout(tmp_path, "rain", 0.0, seed=1)
    write_heldout(tmp_path, "afternoon", 0.0, seed=2)

    def config(weathers: str):
        overrides = ("methods=[vi]", f"weathers={weathers}", "noises=[0.0]")
        return evaluate_config(stage_config, random_models, store_root, tmp_path, *overrides)

    alone = run_evaluate(config("[rain]"))
    both = run_evaluate(config("[afternoon,rain]"))
    assert both.cells["vi"]["rain"] == alone.cells["vi"]["rain"]
    assert both.cell("vi", "rain", 0.0).hmc_tv_distance is None  # no reference, no agreement


def test_auroc_without_mistakes_is_null_with_the_reason():
    labels = torch.tensor([0, 1, 2])
    probs = torch.tensor([[0.8, 0.1, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.8]])
    m = cell_metrics(probs, labels, eta2=torch.tensor([1.0, 0.9, 1.0]), mi=torch.tensor([0.1, 0.2, 0.3]))
    assert m["auroc_mi"] is None and m["auroc_one_minus_eta2"] is None and m["mistakes"] == 0
    assert "no frame of 3 has a wrong class" in m["auroc_note"]
    json.dumps(m, allow_nan=False)  # valid JSON: null, not NaN

    wrong = cell_metrics(
        probs, torch.tensor([0, 1, 0]), eta2=torch.tensor([1.0, 1.0, 0.5]), mi=torch.tensor([0.1, 0.2, 0.3])
    )
    assert wrong["auroc_mi"] == pytest.approx(1.0) and wrong["auroc_one_minus_eta2"] == pytest.approx(1.0)
    assert wrong["auroc_note"] is None and wrong["mean_eta2"] == pytest.approx(2.5 / 3)


def test_missing_inputs_name_the_file_and_how_to_make_it(stage_config, tmp_path, random_models):
    with pytest.raises(
        FileNotFoundError,
        match=r"roundabout-rain-noise0.0.parquet: collect it first "
        r"\(`python stages/collect.py --config-name heldout",
    ):
        run_evaluate(
            evaluate_config(
                stage_config, random_models, tmp_path, tmp_path, "methods=[mcd]", "weathers=[rain]", "noises=[0.0]"
            )
        )
    write_heldout(tmp_path, "rain", 0.0)
    with pytest.raises(
        FileNotFoundError, match=r"vi/seed0.pt: train it first \(`python stages/train.py model=vi seed=0`"
    ):
        run_evaluate(stage_config("evaluate", "methods=[vi]", "weathers=[rain]", "noises=[0.0]"))
    assert not (tmp_path / "metrics").exists()


def test_a_file_of_another_condition_is_refused(stage_config, tmp_path, random_models):
    write_heldout(tmp_path, "clear_noon", 0.0, name="roundabout-rain-noise0.0.parquet")
    with pytest.raises(ValueError, match=r"rain-noise0.0.parquet holds frames of .*weather \['clear_noon'\]"):
        run_evaluate(
            evaluate_config(
                stage_config, random_models, tmp_path, tmp_path, "methods=[mcd]", "weathers=[rain]", "noises=[0.0]"
            )
        )


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("evaluate.eps=0", "evaluate.eps=0: input should be greater than 0"),
        ("evaluate.eps=-0.1", "evaluate.eps=-0.1: input should be greater than 0"),
        ("evaluate.samples=0", "evaluate.samples=0: input should be greater than or equal to 1"),
        ("evaluate.samples=2.5", "evaluate.samples=2.5: input should be a valid integer"),
        ("evaluate.batch_size=0", "evaluate.batch_size=0: input should be greater than or equal to 1"),
        ("methods=[mcd,Bnn]", r"methods\[1\]='Bnn': string should match pattern"),
        ("methods=[]", r"methods=\[\]: tuple should have at least 1 item"),
        ("noises=[-0.1]", r"noises\[0\]=-0.1: input should be greater than or equal to 0"),
        ("weathers=[]", r"weathers=\[\]: tuple should have at least 1 item"),
    ],
)
def test_bad_config_values_fail_before_any_work(stage_config, tmp_path, override, message):
    cfg = stage_config("evaluate", "methods=[mcd]", "weathers=[rain]", "noises=[0.0]", override)
    with pytest.raises(ValueError, match=message):
        run_evaluate(cfg)
    assert not (tmp_path / "metrics").exists()
