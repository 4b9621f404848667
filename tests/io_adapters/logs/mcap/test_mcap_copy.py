"""The MCAP copy annotate writes keeps the data section's channels when the summary says otherwise."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
from conftest import _summary_channel, fix_crcs

from lanecast.io_adapters.logs.mcap import reader as mcap_reader


def _copied(src: Path, out: Path) -> list[tuple[int, int, bytes]]:
    """``src`` copied by annotate's MCAP copy (no forecasts added); the copy's messages as read back
    by the mcap library with every CRC checked."""
    from mcap.reader import make_reader

    from lanecast.io_adapters.logs.mcap import copy as mcap_copy

    with out.open("wb") as f:
        mcap_copy.copy_mcap(src, f)
    with out.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        return [(c.id, m.log_time, m.data) for _s, c, m in reader.iter_messages(log_time_order=False)]


def test_annotate_copies_a_log_whose_summary_channel_differs_from_the_data(
    tmp_path: Path, logs: dict[str, tuple[Path, pa.Table]]
) -> None:
    """The summary's copy of a channel with another topic: annotate's copy put the summary's
    Channel record to the writer, which refused the redefinition; the check that should then name
    the damage counted no messages and blamed the Statistics record ('counts 750 messages, but the
    data section holds 0'). The copy now stops at DataEnd (the summary is written anew from the
    data section) and the output is the log's data, valid with every CRC."""
    src, _ = logs["pb"]
    d = bytearray(src.read_bytes())
    _summary_channel(d)
    fix_crcs(d)
    bad = tmp_path / "summary-channel.mcap"
    bad.write_bytes(bytes(d))
    assert _copied(bad, tmp_path / "out.mcap") == _copied(src, tmp_path / "clean.mcap")
    assert len(mcap_reader.read(tmp_path / "out.mcap")) == logs["pb"][1].num_rows
