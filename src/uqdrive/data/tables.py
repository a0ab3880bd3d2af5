"""Parquet schemas and read/write for raw episodes and preprocessed frames (pyarrow)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from uqdrive.files import atomic_path
from uqdrive.network_input import INPUT_HEIGHT, INPUT_WIDTH

RAW_SCHEMA = pa.schema(
    [
        ("scenario", pa.string()),
        ("weather", pa.string()),
        ("noise", pa.float32()),
        ("episode", pa.int32()),
        ("seed", pa.int64()),
        ("step", pa.int32()),
        ("t", pa.float32()),
        ("x", pa.float32()),
        ("y", pa.float32()),
        ("yaw", pa.float32()),
        ("speed", pa.float32()),
        ("steering", pa.float32()),  # the autopilot's label, positive = left
        ("applied_steering", pa.float32()),  # what was applied (differs during perturbations)
        ("lateral_deviation", pa.float32()),
        ("image", pa.binary()),  # PNG, RGB at render resolution
    ]
)

FRAME_BYTES = INPUT_HEIGHT * INPUT_WIDTH

PROCESSED_SCHEMA = pa.schema(
    [
        ("scenario", pa.string()),
        ("weather", pa.string()),
        ("noise", pa.float32()),
        ("episode", pa.int32()),
        ("step", pa.int32()),
        ("steering", pa.float32()),
        ("label", pa.int16()),
        ("image", pa.binary(FRAME_BYTES)),  # grayscale uint8 48x64, row-major
    ]
)


def write_table_batches(path: str | Path, schema: pa.Schema, batches: Iterable[dict]) -> int:
    """Stream column dicts into one parquet file atomically; returns the number of rows written."""
    rows = 0
    with atomic_path(path) as tmp, pq.ParquetWriter(tmp, schema, compression="zstd") as writer:
        for columns in batches:
            table = pa.Table.from_pydict(columns, schema=schema)
            writer.write_table(table)
            rows += table.num_rows
    return rows


def read_table(path: str | Path, schema: pa.Schema, columns: list[str] | None = None) -> pa.Table:
    """Read a parquet file and check it has the columns this version expects."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist; run the stage that writes it first (dvc repro)")
    try:
        table = pq.read_table(path, columns=columns)
    except (pa.ArrowException, OSError) as err:
        raise ValueError(f"{path} is not a readable parquet file ({err}); rerun the stage that writes it") from None
    missing = sorted(set(columns or schema.names) - set(table.column_names))
    if missing:
        raise ValueError(f"{path} lacks columns {missing}; was it written by another version? rerun its stage")
    return table


def images_to_array(column: pa.ChunkedArray | pa.Array) -> np.ndarray:
    """Fixed-size binary frames → uint8 array [N, 48, 64] without a Python loop."""
    array = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    flat = np.frombuffer(
        array.buffers()[1], dtype=np.uint8, count=len(array) * FRAME_BYTES, offset=array.offset * FRAME_BYTES
    )
    return flat.reshape(len(array), INPUT_HEIGHT, INPUT_WIDTH)
