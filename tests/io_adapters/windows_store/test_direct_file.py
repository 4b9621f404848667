"""Large outputs around the page cache: the bytes equal numpy's, direct or buffered, whatever the
block sizes (smaller than, equal to and across the staging buffer and the alignment)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.windows_store import direct_file
from lanecast.io_adapters.windows_store.direct_file import ALIGN, DirectWriter
from lanecast.io_adapters.windows_store.npy_append import (
    SHARD_HEADER_BYTES,
    NpyAppender,
    read_npy_header,
    save_npy,
)


@pytest.fixture(params=[True, False], ids=["direct", "buffered"])
def direct(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> bool:
    monkeypatch.setattr(direct_file, "STAGE_BYTES", 4 * ALIGN)  # small: many flushes in a test
    return bool(request.param)


@pytest.mark.parametrize("sizes", [[0], [1], [ALIGN - 128], [5 * ALIGN + 7, 3, 9 * ALIGN], [ALIGN] * 6])
def test_written_bytes_and_header_are_exact(tmp_path: Path, direct: bool, sizes: list[int]) -> None:
    rng = np.random.default_rng(len(sizes))
    blocks = [rng.integers(0, 256, size=n, dtype=np.uint8) for n in sizes]
    out = DirectWriter(tmp_path / "f.bin", direct=direct)
    out.write(b"\0" * 128)  # reserved for the header
    for block in blocks:
        out.write(block)
    assert out.size == 128 + sum(sizes)
    out.close(b"H" * 128)
    assert (tmp_path / "f.bin").read_bytes() == b"H" * 128 + b"".join(b.tobytes() for b in blocks)


def test_appended_file_from_an_aligned_offset(tmp_path: Path, direct: bool) -> None:
    rng = np.random.default_rng(3)
    src = rng.integers(0, 256, size=ALIGN + 9 * ALIGN + 77, dtype=np.uint8)
    (tmp_path / "src.bin").write_bytes(src.tobytes())
    out = DirectWriter(tmp_path / "f.bin", direct=direct)
    out.write(b"ab")
    assert out.append_file(tmp_path / "src.bin", ALIGN) == src.size - ALIGN
    assert out.append_file(tmp_path / "src.bin", 5) == src.size - 5  # unaligned: read buffered
    out.close(b"XY")
    assert (tmp_path / "f.bin").read_bytes() == b"XY" + src[ALIGN:].tobytes() + src[5:].tobytes()


def test_arrays_equal_numpy_save_and_shards_append(tmp_path: Path, direct: bool) -> None:
    rng = np.random.default_rng(4)
    blocks = [rng.normal(size=(n, 4, 8, 30)).astype(np.float32) for n in (3, 0, 11)]
    shard = save_npy(tmp_path / "shard.npy", blocks[2], header_bytes=SHARD_HEADER_BYTES)
    assert read_npy_header(shard) == ((11, 4, 8, 30), np.dtype(np.float32), SHARD_HEADER_BYTES)
    np.testing.assert_array_equal(np.load(shard), blocks[2])
    app = NpyAppender(tmp_path / "a.npy", np.dtype(np.float32), (4, 8, 30), direct=direct)
    app.append(blocks[0])
    app.append(blocks[1])
    assert app.append_npy(shard) == 11
    app.close()
    np.save(tmp_path / "b.npy", np.concatenate(blocks))
    assert (tmp_path / "a.npy").read_bytes() == (tmp_path / "b.npy").read_bytes()


def test_a_truncated_shard_is_refused_naming_it(tmp_path: Path) -> None:
    shard = save_npy(tmp_path / "s.npy", np.ones((4, 5, 2), np.float32), header_bytes=SHARD_HEADER_BYTES)
    shard.write_bytes(shard.read_bytes()[:-8])
    app = NpyAppender(tmp_path / "a.npy", np.dtype(np.float32), (5, 2))
    with pytest.raises(InputError, match=r"s\.npy.*bytes of rows"):
        app.append_npy(shard)
    app.abort()


def test_rows_filled_in_place_equal_numpy_save(tmp_path: Path, direct: bool) -> None:
    """reserve -> fill -> append (no copy), the staging memory growing past its first size, mixed
    with copied blocks: the file equals numpy's."""
    rng = np.random.default_rng(5)
    sizes = [2, 40, 1, 90, 3]  # rows of 3840 bytes: 40 and 90 exceed the 4-block staging buffer
    blocks = [rng.normal(size=(n, 4, 8, 30)).astype(np.float32) for n in sizes]
    app = NpyAppender(tmp_path / "a.npy", np.dtype(np.float32), (4, 8, 30), direct=direct)
    _append_and_compare(app, blocks, tmp_path, copy_every_other=True)


def test_committed_rows_written_by_the_thread_while_the_next_are_filled(tmp_path: Path) -> None:
    """Every reserve is filled while the previous commit may still be on its way to the disk (two
    staging buffers alternate): the file equals numpy's, whatever the interleaving."""
    rng = np.random.default_rng(7)
    blocks = [rng.normal(size=(int(n), 4, 8, 30)).astype(np.float32) for n in rng.integers(1, 300, 12)]
    app = NpyAppender(tmp_path / "a.npy", np.dtype(np.float32), (4, 8, 30))
    _append_and_compare(app, blocks, tmp_path, copy_every_other=False)


def _append_and_compare(
    app: NpyAppender, blocks: list[np.ndarray], tmp_path: Path, *, copy_every_other: bool
) -> None:
    """Append ``blocks`` (filled in place through reserve, or every other one copied), close, and
    check that the file equals numpy's save of them all."""
    for i, block in enumerate(blocks):
        if copy_every_other and i % 2:
            app.append(block.copy())
        else:
            rows = app.reserve(len(block))
            rows[...] = block
            app.append(rows)
    app.close()
    np.save(tmp_path / "b.npy", np.concatenate(blocks))
    assert (tmp_path / "a.npy").read_bytes() == (tmp_path / "b.npy").read_bytes()


def test_a_failed_background_write_is_raised_by_the_next_commit_or_close(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = DirectWriter(tmp_path / "f.bin")
    if not out.direct:
        out.abort()
        pytest.skip("no O_DIRECT here: commits are written at once")

    def full(fd: int, data: object, offset: int) -> int:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(direct_file.os, "pwrite", full)
    out.reserve(3 * ALIGN)[:] = b"x" * (3 * ALIGN)
    out.commit(3 * ALIGN)  # handed to the thread
    out.reserve(ALIGN)[:] = b"y" * ALIGN
    with pytest.raises(OSError, match="No space left"):
        out.commit(ALIGN)
    out.abort()
    out.abort()  # idempotent, the thread and the file closed
    out2 = DirectWriter(tmp_path / "g.bin")
    out2.reserve(ALIGN)[:] = b"z" * ALIGN
    out2.commit(ALIGN)
    with pytest.raises(OSError, match="No space left"):
        out2.close(b"")
