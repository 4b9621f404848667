"""Arrow columns read from their buffers (lanecast.io_adapters.arrow_numpy), checked against
pyarrow.compute's answers on chunked, sliced and null-holding columns."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

from lanecast.io_adapters.arrow_numpy import dictionary_codes, filled, holds_any_byte, take, valid_mask


def _columns() -> list[pa.Array | pa.ChunkedArray]:
    """Integer columns with nulls in every position a bitmap can hold them: offsets that are not a
    multiple of eight (slices), several chunks, none null, all null."""
    rng = np.random.default_rng(7)
    values = rng.integers(-(2**62), 2**62, 1000)
    mask = rng.random(1000) < 0.3
    whole = pa.array(values, mask=mask, type=pa.int64())
    return [
        whole,
        whole.slice(3, 501),
        pa.chunked_array([whole.slice(0, 13), whole.slice(13, 600), whole.slice(613)]),
        pa.chunked_array([pa.array([1, 2, 3], pa.int32()), pa.array([None, None], pa.int32())]),
        pa.array([5, 6, 7], pa.int32()),
        pa.chunked_array([], pa.int64()),
    ]


@pytest.mark.parametrize("column", _columns())
def test_valid_mask_and_filled_are_what_arrow_computes(column: pa.Array | pa.ChunkedArray) -> None:
    np.testing.assert_array_equal(valid_mask(column), ~np.asarray(pc.is_null(column), dtype=bool))
    expected = pc.fill_null(column, 0).to_numpy() if len(column) else np.zeros(0)
    got = filled(column, 0)
    np.testing.assert_array_equal(got, expected)
    assert got.dtype == np.dtype(column.type.to_pandas_dtype())  # int64 stays exact


def test_the_null_type_has_no_bitmap_and_no_value() -> None:
    np.testing.assert_array_equal(valid_mask(pa.nulls(4)), np.zeros(4, dtype=bool))


@pytest.mark.parametrize("string_type", [pa.string(), pa.large_string()])
def test_holds_any_byte_looks_only_at_the_values_of_the_column(string_type: pa.DataType) -> None:
    column = pa.array(["a\nb", "car", None, "", "truck", "x\ry"], string_type)
    assert holds_any_byte(column, b"\r\n")
    assert not holds_any_byte(column.slice(1, 4), b"\r\n")  # its neighbours' bytes share the buffer
    assert holds_any_byte(column.slice(5), b"\r")
    assert not holds_any_byte(column.slice(5), b"\n")
    assert holds_any_byte(pa.chunked_array([column.slice(1, 2), column.slice(0, 1)]), b"\n")
    assert not holds_any_byte(pa.array([None, ""], string_type), b"\n")
    assert not holds_any_byte(pa.chunked_array([], string_type), b"\n")


def test_dictionary_codes_are_the_sorted_entries_in_use() -> None:
    names = pa.array(["upper", "lower", "spare"])
    first = pa.DictionaryArray.from_arrays(pa.array([0, 1, 0, 0], pa.int32()), names)
    second = pa.DictionaryArray.from_arrays(pa.array([1, 1], pa.int32()), pa.array(["b", "lower"]))
    column = pa.chunked_array([first.slice(1), second])
    entries, codes = dictionary_codes(column)
    assert entries.tolist() == ["lower", "upper"]  # "spare" and "b" have no row
    assert entries[codes].tolist() == column.cast(pa.string()).to_pylist()


@pytest.mark.parametrize("column", _columns())
def test_take_is_arrows_take(column: pa.Array | pa.ChunkedArray) -> None:
    order = np.random.default_rng(3).permutation(len(column))[: max(len(column) - 2, 0)]
    assert take(column, order).to_pylist() == pc.take(column, pa.array(order, pa.int64())).to_pylist()
    assert take(column, order).type == column.type


def test_take_of_dictionary_strings_and_floats() -> None:
    names = pa.DictionaryArray.from_arrays(pa.array([1, 0, None, 1], pa.int32()), pa.array(["a", "b"]))
    order = np.array([3, 2, 0, 0])
    assert take(pa.chunked_array([names.slice(0, 1), names.slice(1)]), order).to_pylist() == [
        "b",
        None,
        "b",
        "b",
    ]
    other = pa.DictionaryArray.from_arrays(pa.array([0], pa.int32()), pa.array(["c"]))
    assert take(pa.chunked_array([names, other]), np.array([4, 0])).to_pylist() == [
        "c",
        "b",
    ]  # two dictionaries
    floats = pa.array([0.5, None, -2.0], pa.float32())
    assert take(floats, np.array([2, 1, 0])).to_pylist() == [-2.0, None, 0.5]
    assert take(pa.array(["x", "y"]), np.array([1, 1])).to_pylist() == ["y", "y"]  # other types: Arrow's
