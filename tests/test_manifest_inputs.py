"""Bulk annotation's inputs and its OUT_DIR/manifest.jsonl in unusual but legitimate forms (linked
folders, a manifest saved by an editor) and hostile ones (a FIFO, a damaged entry): read as meant,
or one clear error naming the file; never a traceback or a hang."""

from __future__ import annotations

from pathlib import Path

import pyarrow.parquet as pq
from conftest import forecasts_for, make_mcap

from lanecast.workflows.annotate_log import AnnotateOptions
from lanecast.workflows.bulk import run_bulk


def _log(folder: Path, name: str, fc: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    fc.mkdir(exist_ok=True)
    pq.write_table(forecasts_for(name, [1], [1]), fc / f"{name}.parquet")
    return make_mcap(folder / f"{name}.mcap", n=20)


def test_logs_in_a_linked_folder_or_linked_in_from_elsewhere_are_annotated(tmp_path: Path) -> None:
    """A folder reached through a symbolic link (``data -> /mnt/disk/data``), or a log linked into
    the folder from elsewhere, failed with a ValueError traceback ('... is not in the subpath of
    ...'): logs were named by where the links lead, outside the folder given."""
    fc = tmp_path / "fc"
    _log(tmp_path / "disk" / "logs", "a", fc)
    (tmp_path / "data").symlink_to(tmp_path / "disk" / "logs")
    (tmp_path / "elsewhere").mkdir()
    _log(tmp_path / "elsewhere", "b", fc)
    (tmp_path / "disk" / "logs" / "b.mcap").symlink_to(tmp_path / "elsewhere" / "b.mcap")
    out = tmp_path / "out"
    result = run_bulk([tmp_path / "data"], out, AnnotateOptions(forecasts=fc))
    assert len(result.done) == 2 and sorted(p.name for p in out.glob("*.mcap")) == ["a.mcap", "b.mcap"]
    again = run_bulk([tmp_path / "disk" / "logs"], out, AnnotateOptions(forecasts=fc))  # the same logs
    assert len(again.skipped) == 2 and not again.entries
