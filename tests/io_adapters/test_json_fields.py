"""JSON files saved with a UTF-8 byte order mark (a training config, a windows manifest) are read."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import synthetic_windows

from lanecast.io_adapters.windows_store.dataset import load_windows, save_windows


def test_json_with_a_utf8_byte_order_mark_is_read(tmp_path: Path) -> None:
    """Windows editors save "UTF-8" JSON with a BOM: a training config or a windows manifest.json
    so saved was refused ("Unexpected UTF-8 BOM")."""
    from lanecast.models.train import TrainConfig

    config = tmp_path / "config.json"
    config.write_bytes(b'\xef\xbb\xbf{\r\n  "epochs": 3\r\n}\r\n')
    assert TrainConfig.from_file(config).epochs == 3
    directory = save_windows(synthetic_windows(n=20), tmp_path / "windows")
    manifest = directory / "manifest.json"
    manifest.write_bytes(b"\xef\xbb\xbf" + manifest.read_bytes())
    assert load_windows(directory).manifest == json.loads(manifest.read_bytes()[3:])
