"""The track table's schema and metadata (docs/design.md §1): the columns, their types and units,
the value ranges the checks hold them to, the ``lanecast`` metadata document (source format,
source files and, per recording, the frame rate, the coordinate frame and the source's extras),
and how the columns are encoded in Parquet.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters import json_fields
from lanecast.io_adapters.errors import TrackTableError

SCHEMA_VERSION = 1
META_KEY = b"lanecast"

NEIGHBOUR_COLUMNS: tuple[str, ...] = (
    "preceding_id",
    "following_id",
    "left_preceding_id",
    "left_alongside_id",
    "left_following_id",
    "right_preceding_id",
    "right_alongside_id",
    "right_following_id",
)


def _field(name: str, type_: pa.DataType, unit: str | None = None, nullable: bool = False) -> pa.Field:
    metadata = {b"unit": unit.encode()} if unit else None
    return pa.field(name, type_, nullable=nullable, metadata=metadata)


_DICT = pa.dictionary(pa.int32(), pa.string())

REQUIRED_FIELDS: tuple[pa.Field, ...] = (
    _field("recording", _DICT),
    _field("track_id", pa.int64()),
    _field("frame", pa.int64()),
    _field("time_ns", pa.int64(), "ns"),
    _field("x", pa.float64(), "m"),
    _field("y", pa.float64(), "m"),
    _field("heading", pa.float32(), "rad"),
    _field("vx", pa.float32(), "m/s"),
    _field("vy", pa.float32(), "m/s"),
    _field("ax", pa.float32(), "m/s^2"),
    _field("ay", pa.float32(), "m/s^2"),
    _field("length", pa.float32(), "m"),
    _field("width", pa.float32(), "m"),
    _field("lane_id", pa.int32(), nullable=True),
    _field("object_class", _DICT),
)
OPTIONAL_FIELDS: tuple[pa.Field, ...] = tuple(
    _field(name, pa.int64(), nullable=True) for name in NEIGHBOUR_COLUMNS
)
REQUIRED_COLUMNS: tuple[str, ...] = tuple(f.name for f in REQUIRED_FIELDS)
UNITS: dict[str, str] = {
    f.name: f.metadata[b"unit"].decode() for f in REQUIRED_FIELDS if f.metadata and b"unit" in f.metadata
}
# Columns that must never hold NaN, inf or null.
FINITE_COLUMNS: tuple[str, ...] = ("x", "y", "heading", "vx", "vy", "ax", "ay", "length", "width")
FIELDS_BY_NAME = {f.name: f for f in REQUIRED_FIELDS + OPTIONAL_FIELDS}
# Finite values that still cannot be: positions so far out that differences of them overflow the
# float32 windows (inf in inputs.npy; checked with the finite columns), negative sizes, times before
# 0 (which no log or dataset has, and no log can be written with), speeds and accelerations as far
# out (a vx of 3e38 m/s, finite in float32, made window inputs that overflowed the normalisation
# statistics of train). (column, limit, expected): |value| <= a positive limit, value >= a limit of 0.
MAX_POSITION_M = 1e9
RANGES: tuple[tuple[str, float, str], ...] = (
    ("length", 0.0, "a size >= 0 m"),
    ("width", 0.0, "a size >= 0 m"),
    ("time_ns", 0, "a time >= 0 ns (a log time, or frame / rate)"),
    *((name, MAX_POSITION_M, f"a speed within ±{MAX_POSITION_M:g} m/s") for name in ("vx", "vy")),
    *((name, MAX_POSITION_M, f"an acceleration within ±{MAX_POSITION_M:g} m/s^2") for name in ("ax", "ay")),
)


#: Frame rates a recording may have (Hz): below 0.1 Hz there is no trajectory to forecast at 10 Hz
#: (a highD frameRate of 1e-9 put frame 5 in the year 2128), above 1 kHz no traffic sensor records.
FRAME_RATE_MIN, FRAME_RATE_MAX = 0.1, 1000.0
FRAME_RATES = f"from {FRAME_RATE_MIN:g} to {FRAME_RATE_MAX:g} Hz"


def plausible_frame_rate(rate: object) -> bool:
    """``rate`` is a number (not bool) from FRAME_RATE_MIN to FRAME_RATE_MAX Hz."""
    return (
        isinstance(rate, (int, float, np.floating, np.integer))
        and not isinstance(rate, bool)
        and FRAME_RATE_MIN <= float(rate) <= FRAME_RATE_MAX
    )


@dataclass
class RecordingMeta:
    """What is known about one recording: its rate, its coordinate frame and the source's extras."""

    frame_rate: float
    coordinate_frame: str = "road"  # "road" (x along travel, y left), or a log's fixed frame id
    source_files: list[str] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class TableMeta:
    """The table-level metadata document stored under the schema metadata key ``lanecast``."""

    source_format: str
    recordings: dict[str, RecordingMeta]
    source_files: list[str] = field(default_factory=list)

    @property
    def frame_rate(self) -> float | None:
        """The common frame rate of all recordings, or None where they differ."""
        rates = {r.frame_rate for r in self.recordings.values()}
        return rates.pop() if len(rates) == 1 else None

    def to_json(self) -> str:
        doc = {
            "schema_version": SCHEMA_VERSION,
            "frame_rate": self.frame_rate,
            "source_format": self.source_format,
            "source_files": self.source_files,
            "units": UNITS,
            "recordings": {name: asdict(rec) for name, rec in self.recordings.items()},
        }
        return json.dumps(doc, sort_keys=True)

    @classmethod
    def from_json(cls, text: str | bytes) -> TableMeta:
        """Parse the document, every field checked (FieldError naming the field otherwise)."""
        doc = json_fields.check(json_fields.loads(text, "lanecast"), "lanecast", "object")
        recordings = {}
        for name, rec in json_fields.get(doc, "recordings", "", "object").items():
            where = f"recordings.{name}"
            json_fields.check(rec, where, "object")
            rate = json_fields.get(rec, "frame_rate", where, "positive")
            if not plausible_frame_rate(rate):
                raise json_fields.FieldError(f"{where}.frame_rate", f"{rate:g} Hz", f"a rate {FRAME_RATES}")
            recordings[name] = RecordingMeta(
                frame_rate=float(rate),
                coordinate_frame=json_fields.get(rec, "coordinate_frame", where, "str", "road"),
                source_files=list(json_fields.get(rec, "source_files", where, "str_list", [])),
                extra=dict(json_fields.get(rec, "extra", where, "object", {})),
            )
        return cls(
            json_fields.get(doc, "source_format", "", "str"),
            recordings,
            list(json_fields.get(doc, "source_files", "", "str_list", [])),
        )


def neighbour_ids(ids: np.ndarray) -> pa.Array:
    """Vehicle ids [n] as a neighbour column (int64, null for none): 0, highD's and NGSIM's "no
    vehicle", becomes null. Built on the ids' own buffer with a validity bitmap (``pa.array`` with a
    mask copies and takes eight times as long)."""
    ids = np.ascontiguousarray(ids, dtype=np.int64)
    valid = ids != 0
    bitmap = pa.py_buffer(np.packbits(valid, bitorder="little"))
    return pa.Array.from_buffers(
        pa.int64(), ids.size, [bitmap, pa.py_buffer(ids)], null_count=ids.size - int(np.count_nonzero(valid))
    )


def schema(with_neighbours: bool) -> pa.Schema:
    """The Arrow schema of a track table, with or without the eight neighbour id columns."""
    fields = REQUIRED_FIELDS + (OPTIONAL_FIELDS if with_neighbours else ())
    return pa.schema(list(fields))


def read_meta(table: pa.Table | pa.Schema, source: str | Path | None = None) -> TableMeta:
    """The ``lanecast`` metadata document of a track table (errors name ``source``, the file)."""
    schema_ = table if isinstance(table, pa.Schema) else table.schema
    where = f"{source}: " if source is not None else ""
    raw = (schema_.metadata or {}).get(META_KEY)
    if raw is None:
        raise TrackTableError(
            f"{where}the table carries no 'lanecast' schema metadata (not a lanecast track table); expected "
            "a Parquet file written by `lanecast convert`, or one filtered and written back with pyarrow "
            "(a pandas DataFrame written back loses the metadata: copy the original file's 'lanecast' "
            "schema metadata over)"
        )
    try:
        return TableMeta.from_json(raw)
    except json_fields.FieldError as exc:
        raise TrackTableError(f"{where}bad 'lanecast' schema metadata: {exc}") from exc


#: rows per Parquet row group of written track tables (a chunk of a long recording reads the groups
#: that hold its context: small groups, little decoded in vain)
ROW_GROUP_ROWS = 1 << 17
#: columns that step by a constant along each track: delta-encoded they take a few bits a row (a
#: dictionary of them took 12 times the space and twice the time to write)
DELTA_COLUMNS = ("frame", "time_ns")
#: columns whose min/max says nothing a reader can skip by (every row group holds cars and trucks)
NO_STATISTICS = ("object_class",)


def parquet_options(schema: pa.Schema) -> dict[str, Any]:
    """How every track table is written as Parquet: zstd; page checksums, so that a flipped byte in
    the data is refused on reading instead of read as a value; dictionary encoding for the ids,
    lanes and names; delta encoding for frames and times; the floats' bytes split into streams
    (``BYTE_STREAM_SPLIT``: a float's sign and exponent bytes compress well apart from its noisy
    mantissa; a dictionary of nearly distinct floats was built and dropped, a quarter of the
    write's time)."""
    names = schema.names
    floats = [f.name for f in schema if pa.types.is_floating(f.type)]
    return {
        "compression": "zstd",
        "write_page_checksum": True,
        "use_dictionary": [name for name in names if name not in floats and name not in DELTA_COLUMNS],
        "column_encoding": {
            **{name: "DELTA_BINARY_PACKED" for name in DELTA_COLUMNS if name in names},
            **dict.fromkeys(floats, "BYTE_STREAM_SPLIT"),
        },
        "write_statistics": [name for name in names if name not in NO_STATISTICS],
        "write_batch_size": 8192,  # values encoded at a time (Arrow: 1024): the same pages, 6 % faster
    }
