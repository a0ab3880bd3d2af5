"""A record that embeds a result in a `flattened` field writes the result's keys beside its own and reads them back
into the embedded result, at any depth, with read_record's checks (NaN for null, one-line errors) intact."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from uqdrive.records import flattened, read_record, record, write_record
from uqdrive.schema import ConfigError


@dataclasses.dataclass(frozen=True)
class Decided:
    estimate: float
    replicates: tuple[int, ...]


@record
class Row:
    name: str
    decided: Decided = flattened()
    pairs: int = 0


@record
class Table:
    rows: list[Row]


@record
class Clashing:
    estimate: float
    decided: Decided = flattened()


def test_a_flattened_result_is_written_flat_and_read_back_embedded(tmp_path):
    table = Table([Row("a", Decided(0.5, (0, 1)), 3), Row("b", Decided(math.nan, ()), 4)])
    path = write_record(tmp_path / "t.json", table)
    rows = json.loads(path.read_text())["rows"]
    assert rows[0] == {"name": "a", "estimate": 0.5, "replicates": [0, 1], "pairs": 3}
    assert rows[1]["estimate"] is None  # NaN is written null
    back = read_record(Table, path, "stage")
    assert back.rows[0] == table.rows[0] and back.rows[1].name == "b"
    assert math.isnan(back.rows[1].decided.estimate) and back.rows[1].decided.replicates == ()


def test_a_flattened_results_keys_are_checked_as_the_records_own(tmp_path):
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"rows": [{"name": "a", "estimate": 0.5, "replicates": [0], "pairs": 1, "extra": 1}]}))
    with pytest.raises(ConfigError, match="extra: unknown key"):
        read_record(Table, path, "stage")
    path.write_text(json.dumps({"rows": [{"name": "a", "replicates": [0], "pairs": 1}]}))
    with pytest.raises(ConfigError, match="estimate is required"):
        read_record(Table, path, "stage")


def test_a_flattened_result_may_not_repeat_the_records_keys(tmp_path):
    with pytest.raises(ValueError, match=r"Clashing.decided repeats the record's keys \['estimate'\]"):
        write_record(tmp_path / "c.json", Clashing(1.0, Decided(2.0, ())))


@dataclasses.dataclass(frozen=True)
class Interval:
    value: float
    low: float
    label: str = ""


@record
class Cell:
    name: str
    interval: Interval = flattened({"value": "eta1", "low": "eta1_low"}, left=("label",))


def test_a_flattened_result_keeps_the_files_names_and_leaves_out_what_the_file_does_not_hold(tmp_path):
    path = write_record(tmp_path / "c.json", Cell("a", Interval(0.75, 0.5)))
    assert json.loads(path.read_text()) == {"name": "a", "eta1": 0.75, "eta1_low": 0.5}
    assert read_record(Cell, path, "stage") == Cell("a", Interval(0.75, 0.5))
    path.write_text(json.dumps({"name": "a", "eta1": 0.75, "eta1_low": 0.5, "value": 1.0}))
    with pytest.raises(ConfigError, match="value: unknown key"):  # the field's own name is not its key
        read_record(Cell, path, "stage")
    with pytest.raises(ValueError, match=r"Cell.interval.label is not kept in its file: 'x'"):
        write_record(tmp_path / "d.json", Cell("a", Interval(0.75, 0.5, "x")))
