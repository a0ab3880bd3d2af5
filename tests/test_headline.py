"""The headline numbers mean what their names say: metrics/summary.json's η̂1 equal what the committed cells' records
give for the cells each key names (none left out silently), they come first in `dvc exp show`, and no file
holds a NaN."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from uqdrive.files import MISSING, write_csv
from uqdrive.records import read_record, record, write_record
from uqdrive.report.headline import read_summary
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.uq.replicates import replicate_bounded_interval

ROOT = Path(__file__).resolve().parents[1]
PARAMS = yaml.safe_load((ROOT / "params.yaml").read_text())


def committed_cells() -> list[SafetyCell]:
    return [read_record(SafetyCell, p, "safety") for p in sorted((ROOT / "metrics/safety").glob("*.json"))]


def from_cells(cells: list[SafetyCell], method: str, keep) -> tuple[float, float, float, int]:
    """The mean over replicates of each replicate's mean η̂1 over the kept cells, its bound, how many cells."""
    replicates = sorted({c.replicate for c in cells})
    per_replicate, counted = [], 0
    for r in replicates:
        mine = [c for c in cells if c.method == method and c.replicate == r and keep(c)]
        counted = len(mine)
        per_replicate.append(np.mean([c.safe[: c.fixed_rollouts].mean() for c in mine]))
    bound = replicate_bounded_interval(per_replicate, 0.05)
    return bound.value, bound.low, bound.high, counted


def test_the_committed_summary_holds_what_the_cells_give():
    summary = json.loads((ROOT / "metrics/summary.json").read_text())  # flat short names: `dvc exp show`'s columns
    cells = committed_cells()
    location, weather = PARAMS["locations"][0], PARAMS["train_weather"]
    sweep = len(PARAMS["locations"]) * len(PARAMS["weathers"]) * len(PARAMS["noises"])
    keys = {
        "eta1.train": lambda c: c.condition == (location, weather, 0.0),
        "eta1.loc": lambda c: c.location == location,
        "eta1.sweep": lambda c: True,
    }
    expected_counts = {"eta1.train": 1, "eta1.loc": sweep // len(PARAMS["locations"])}
    for key, keep in keys.items():
        for method in PARAMS["methods"]:
            value, low, high, counted = from_cells(cells, method, keep)
            assert counted == expected_counts.get(key, sweep), (key, counted)  # every cell the name covers
            got = tuple(summary[f"{key}.{method}{end}"] for end in ("", ".low", ".high"))
            assert got == pytest.approx((value, low, high), abs=1e-12), key
    assert summary["eta1.sweep.mcd"] < summary["eta1.train.mcd"]


def test_the_headline_comes_first_in_dvc_exp_show_in_short_names():
    summary = json.loads((ROOT / "metrics/summary.json").read_text())
    ends = ("", ".low", ".high", ".ctl_low", ".ctl_high")  # the method's interval, then these controllers'
    first = [f"eta1.train.{m}{end}" for m in PARAMS["methods"] for end in ends]
    assert list(summary)[: len(first) + 1] == [*first, "findings"]
    assert max(len(k) for k in summary) <= 24  # `dvc exp show` gives each a column
    headline = read_summary(ROOT / "metrics/summary.json")  # and reads back as the record the report wrote
    assert list(headline.eta1_training_condition) == PARAMS["methods"]
    assert headline.findings_supported == summary["findings"]


@record
class _Means:
    mean: float
    maybe: float | None
    nested: dict[str, list[float]]


def test_no_nan_reaches_a_json_or_csv_file_and_a_record_reads_it_back(tmp_path):
    path = write_record(tmp_path / "r.json", _Means(math.nan, math.nan, {"a": [1.0, math.nan]}))
    text = path.read_text()
    assert "NaN" not in text and json.loads(text) == {"mean": None, "maybe": None, "nested": {"a": [1.0, None]}}
    back = read_record(_Means, path, "x")
    assert math.isnan(back.mean) and back.maybe is None and math.isnan(back.nested["a"][1])
    csv_path = write_csv(tmp_path / "r.csv", [{"seed": 1, "mean_eta2": math.nan}, {"seed": 2, "mean_eta2": None}])
    assert csv_path.read_text().splitlines()[1:] == [f"1,{MISSING}", f"2,{MISSING}"]
