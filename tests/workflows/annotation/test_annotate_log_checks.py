"""annotate_log names a damaged log (ROS 1 and ROS 2 bags, a file of only the MCAP magic) as
convert does."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pytest
from conftest import _ros1_damage, _small_chunks_ros1_bag, mcap_record_spans, staggered_cars

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer
from lanecast.workflows.cli import main


def test_annotate_names_a_ros1_bag_of_another_version_as_convert_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A ROS 1 bag whose version line says 1.2: convert named offset 0 and the version, annotate
    said only 'cannot open the bag: Bag version 102 is not supported.' (rosbags' words)."""
    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    bag = rosbag_writer.write(table, tmp_path / "old.bag", "ros1")
    bag.write_bytes(b"#ROSBAG V1.2\n" + bag.read_bytes()[13:])
    capsys.readouterr()
    assert main(["annotate", str(bag), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        f"lanecast annotate: error: {bag}, offset 0: a ROS 1 bag of another format version ('#ROSBAG V1.2') "
        "(expected '#ROSBAG V2.0' (the only ROS 1 bag version lanecast reads))"
    )


def test_annotating_a_file_of_only_the_mcap_magic_says_it_is_truncated(tmp_path: Path) -> None:
    """'cannot read the MCAP header: ' (the mcap library's empty message) at offset 0; now the
    reader's own error: truncated at 8 bytes, without a footer."""
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log

    log = tmp_path / "log.mcap"
    log.write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(LogError, match="the file is truncated: it ends at 8 bytes without a footer") as err:
        annotate_log(log, tmp_path / "out.mcap", AnnotateOptions())
    assert err.value.offset == 8
    log.write_bytes(b"")
    with pytest.raises(LogError, match="the file is empty"):
        annotate_log(log, tmp_path / "out.mcap", AnnotateOptions())


@pytest.mark.parametrize(
    "kind",
    [
        "index_pos not at a record",
        "connection without message definition",
        "chunk info listing a listed chunk",
    ],
)
def test_annotate_names_the_damaged_record_of_a_ros1_bag_as_convert_does(
    tmp_path: Path, table: pa.Table, kind: str
) -> None:
    """annotate opens a bag to list its topics before reading it; a bag rosbags could not open
    there was 'cannot open the bag: Header could not be read from file.' (fuzz seed 1101), no
    offset, where convert names the record. Now annotate gives convert's error."""
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log

    bag = _small_chunks_ros1_bag(table, tmp_path / "b.bag")
    data = bytearray(bag.read_bytes())
    offset, text = _ros1_damage(kind, data)
    bag.write_bytes(bytes(data))
    with pytest.raises(LogError) as err:
        annotate_log(bag, tmp_path / "out.mcap", AnnotateOptions())
    assert err.value.path == str(bag) and err.value.offset == offset, str(err.value)
    assert text in str(err.value)
    assert not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_annotate_names_a_damaged_ros2_bag_as_convert_does(
    tmp_path: Path, table: pa.Table, storage: str
) -> None:
    """annotate lists a ROS 2 bag's topics with rosbags before reading it; a bad metadata.yaml
    version or an MCAP storage file with a record deleted was 'cannot open the bag: Invalid bag
    metadata: '>' not supported between instances of 'str' and 'int'' or 'cannot open the bag:'
    with nothing after it (fuzz seeds 1382, 1386). Now convert's error: the file and line/offset."""
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage=storage)
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("version: 9", "version: x"))
    with pytest.raises(LogError, match="version") as err:
        annotate_log(bag, tmp_path / "out", AnnotateOptions())
    assert err.value.path == str(meta) and err.value.line is not None
    if storage == "mcap":
        meta.write_text(meta.read_text().replace("version: x", "version: 9"))
        storage_file = next(bag.glob("*.mcap"))
        data = storage_file.read_bytes()
        end = next(o for o, op, _ in mcap_record_spans(data) if op == 0x0F)
        storage_file.write_bytes(data[:end] + data[end + 13 :])  # the DataEnd record deleted
        with pytest.raises(LogError) as err:
            annotate_log(bag, tmp_path / "out", AnnotateOptions())
        assert err.value.path == str(storage_file) and err.value.offset is not None, str(err.value)
    assert not (tmp_path / "out").exists()


def test_a_chunk_whose_crc_fails_is_named_and_nothing_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """annotate's first pass leaves the CRCs to the copy, which checks every one before the output
    is kept: a flipped byte inside a chunk is still named by its offset, and no log is written."""
    from conftest import chunks, uncompressed

    from lanecast.io_adapters.formats import registry

    table = staggered_cars(4, 80, stagger=5, step_m=2.5, speed=25.0, rate=25.0)
    log = registry.write_any(table, tmp_path / "log.mcap", "mcap", chunk_size=2000)
    plain = uncompressed(log, tmp_path / "plain.mcap")  # a flipped byte decodes: only its CRC tells
    data = bytearray(plain.read_bytes())
    second = chunks(bytes(data))[1]
    data[second + 200] ^= 0x01
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    assert main(["annotate", str(bad), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert f"{bad}, offset {second}: corrupt chunk: CRC mismatch" in err, err[-500:]
    assert not (tmp_path / "out" / "bad.mcap").exists()
