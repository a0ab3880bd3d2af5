import numpy as np
import pyarrow as pa
import pytest

from uqdrive.data.binning import SteeringBins
from uqdrive.data.frames import decode_png, encode_png
from uqdrive.data.preprocess import Split, class_histogram, preprocess_raw
from uqdrive.data.tables import PROCESSED_SCHEMA, RAW_SCHEMA, images_to_array, read_table, write_table_batches
from uqdrive.network_input import preprocess_frame


def _rgb(seed: int, height: int = 120, width: int = 160) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)


def test_preprocess_frame_is_gray_64x48_and_keeps_mean_brightness():
    rgb = _rgb(0)
    out = preprocess_frame(rgb)
    assert out.shape == (48, 64) and out.dtype == np.uint8
    gray_mean = (0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]).mean()
    assert abs(out.mean() - gray_mean) < 1.0


def test_preprocess_frame_rejects_non_rgb_input():
    with pytest.raises(ValueError, match="RGB uint8"):
        preprocess_frame(np.zeros((48, 64), dtype=np.uint8))
    with pytest.raises(ValueError, match="float"):
        preprocess_frame(np.zeros((48, 64, 3), dtype=np.float32))


def test_png_round_trip_is_lossless():
    rgb = _rgb(1)
    np.testing.assert_array_equal(decode_png(encode_png(rgb)), rgb)
    gray = preprocess_frame(rgb)
    np.testing.assert_array_equal(decode_png(encode_png(gray)), gray)


def _raw_table(episodes: int, steps: int) -> pa.Table:
    rows = {name: [] for name in RAW_SCHEMA.names}
    rng = np.random.default_rng(0)
    for e in range(episodes):
        for s in range(steps):
            for name, value in dict(
                scenario="straight",
                weather="clear_noon",
                noise=0.0,
                episode=e,
                seed=100 + e,
                step=s,
                t=s / 15,
                x=float(s),
                y=0.0,
                yaw=0.0,
                speed=8.0,
                steering=float(rng.uniform(-0.3, 0.3)),
                applied_steering=0.0,
                lateral_deviation=0.0,
                image=encode_png(_rgb(e * steps + s, 60, 80)),
            ).items():
                rows[name].append(value)
    return pa.Table.from_pydict(rows, schema=RAW_SCHEMA)


def test_preprocess_splits_whole_episodes_and_labels_by_binning():
    raw = _raw_table(episodes=5, steps=3)
    bins = SteeringBins()
    train, val = preprocess_raw(raw, bins, Split(val_fraction=0.4, seed=0))
    assert train.num_rows + val.num_rows == raw.num_rows
    train_eps, val_eps = set(train.column("episode").to_pylist()), set(val.column("episode").to_pylist())
    assert len(val_eps) == 2 and not train_eps & val_eps
    np.testing.assert_array_equal(train.column("label").to_numpy(), bins.to_class(train.column("steering").to_numpy()))
    frames = images_to_array(train.column("image"))
    assert frames.shape == (train.num_rows, 48, 64)
    first = raw.filter(pa.compute.equal(raw.column("episode"), train.column("episode")[0]))
    np.testing.assert_array_equal(frames[0], preprocess_frame(decode_png(first.column("image")[0].as_py())))


def test_split_is_seeded_and_keeps_one_episode_each_side():
    split = Split(val_fraction=0.01, seed=3)
    assert split.val_episodes(np.arange(10)) == Split(val_fraction=0.01, seed=3).val_episodes(np.arange(10))
    assert len(split.val_episodes(np.arange(10))) == 1
    assert len(Split(val_fraction=0.9).val_episodes(np.arange(2))) == 1
    with pytest.raises(ValueError, match="val_fraction"):
        Split(val_fraction=1.0)


def test_empty_raw_table_is_a_clear_error():
    with pytest.raises(ValueError, match="no frames"):
        preprocess_raw(RAW_SCHEMA.empty_table(), SteeringBins(), Split())


def test_parquet_round_trip_and_missing_file(tmp_path):
    train, _ = preprocess_raw(_raw_table(2, 2), SteeringBins(), Split(val_fraction=0.0))
    path = tmp_path / "frames.parquet"
    assert write_table_batches(path, PROCESSED_SCHEMA, [train.to_pydict()]) == 4
    back = read_table(path, PROCESSED_SCHEMA)
    assert back.equals(train)
    assert not list(tmp_path.glob(".*tmp*"))
    with pytest.raises(FileNotFoundError, match="dvc repro"):
        read_table(tmp_path / "missing.parquet", PROCESSED_SCHEMA)
    np.testing.assert_array_equal(class_histogram(back.column("label").to_numpy(), SteeringBins()).sum(), 4)


def test_interrupted_write_leaves_no_file(tmp_path):
    path = tmp_path / "out.parquet"

    def batches():
        yield _raw_table(1, 1).to_pydict()
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_table_batches(path, RAW_SCHEMA, batches())
    assert not path.exists() and not list(tmp_path.iterdir())
