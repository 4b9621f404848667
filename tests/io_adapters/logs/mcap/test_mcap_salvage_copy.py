"""`annotate --salvage`: the intact chunks of a damaged MCAP are copied, an intact log whole."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pytest
from conftest import chunk_records, chunks, message_times

from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.workflows.cli import main


def _originals(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of every message not on lanecast's own topics, in file order, read
    by the mcap library with every CRC checked."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        return [
            (c.topic, m.log_time, bytes(m.data))
            for _s, c, m in reader.iter_messages(log_time_order=False)
            if not c.topic.startswith("/lanecast/")
        ]


def test_annotate_salvage_writes_the_intact_chunks_of_a_damaged_log(
    tmp_path: Path, logs: dict[str, tuple[Path, pa.Table]], capsys: pytest.CaptureFixture[str]
) -> None:
    """`lanecast annotate --salvage` on an MCAP with a chunk whose CRC fails: the option did not
    exist (argparse's usage error), and without it the log is refused. Now the output is a complete
    MCAP (every CRC valid) holding every message of the intact chunks, byte for byte and in order,
    plus the forecasts; the loss is reported as convert --salvage reports it."""
    src, _ = logs["pb"]
    d = bytearray(src.read_bytes())
    chunk = [c for c in chunks(bytes(d)) if len(message_times(bytes(d), c)) > 1][3]
    start, recs = chunk_records(bytes(d), chunk)
    d[start + recs[-1][0] + 9 + 22] ^= 0xFF  # a payload byte: the chunk's CRC no longer holds
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(d))
    lost = set(message_times(bytes(d), chunk))
    capsys.readouterr()
    assert main(["annotate", str(bad), "--out", str(tmp_path / "out"), "--salvage"]) == 0
    err = capsys.readouterr().err
    assert f"lost 1 chunks with {len(lost)} messages (offset {chunk}: corrupt chunk: CRC mismatch" in err
    out = tmp_path / "out" / "damaged.mcap"
    intact = [m for m in _originals(src) if m[1] not in lost]
    assert _originals(out) == intact and len(intact) < len(_originals(src))
    table = mcap_reader.read(out)
    assert table.num_rows == mcap_reader.read_log(bad, salvage=True)[0].num_rows


def test_annotate_salvage_of_an_intact_log_copies_all_of_it(
    tmp_path: Path, logs: dict[str, tuple[Path, pa.Table]]
) -> None:
    """--salvage changes nothing for an intact log: the same original messages as without it."""
    src, _ = logs["cdr"]
    assert main(["annotate", str(src), "--out", str(tmp_path / "a"), "--salvage"]) == 0
    assert main(["annotate", str(src), "--out", str(tmp_path / "b")]) == 0
    salvaged, plain = tmp_path / "a" / src.name, tmp_path / "b" / src.name
    assert _originals(salvaged) == _originals(plain) == _originals(src)
    assert len(mcap_reader.read(salvaged)) == len(mcap_reader.read(plain))
