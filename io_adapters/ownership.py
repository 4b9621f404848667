"""Whether lanecast wrote a file: the rule that keeps every command from overwriting a user's own files.

A command replaces an existing output only if lanecast itself wrote it, recognised by the mark each
kind of output carries (docs/design.md §6), or if the user says ``--force``:

- Parquet: the ``lanecast`` key in the Arrow schema metadata (every track table has it);
- MCAP: the header's ``library`` field starts with ``lanecast`` (the writer and the annotated copy);
- ROS 1 bag and ROS 2 bag directory: a ``/lanecast/metadata`` connection (ROS 2 also its
  ``custom_data``);
- HTML: ``<meta name='generator' content='lanecast'>``; Markdown: a first line ``<!-- lanecast -->``;
  JSON: a ``generator`` (top level or in ``meta``) or a ``format`` starting with ``lanecast``; PNG: a ``Software`` text chunk
  starting with ``lanecast``; a model's ``.safetensors`` and card: the card's ``format``;
- an empty file (an interrupted copy of someone's, or ``touch``): nothing to lose.

Anything else at the path is named and refused before the work starts.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pyarrow as pa

from lanecast.io_adapters.errors import OutputError

MARK = "lanecast"
#: The ``generator`` of the JSON documents lanecast writes (``meta.generator`` in metrics.json).
GENERATOR = "lanecast"
#: The first line of every Markdown document lanecast writes (invisible when rendered).
MARKDOWN_MARK = "<!-- lanecast -->"
#: In the <head> of every HTML page lanecast writes.
HTML_MARK = "<meta name='generator' content='lanecast'>"
#: The PNG text chunk lanecast's plots carry (``savefig(metadata=PNG_METADATA)``).
PNG_METADATA = {"Software": "lanecast"}
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_HEAD_BYTES = 8192


def _head(path: Path, n: int = _HEAD_BYTES) -> bytes:
    with path.open("rb") as fh:
        return fh.read(n)


def _parquet(path: Path) -> bool:
    import pyarrow.parquet as pq  # only where an output may replace a file: 0.02–0.03 s of start-up

    try:
        metadata = pq.read_schema(path).metadata or {}
    except (pa.ArrowException, OSError):
        return False
    return MARK.encode() in metadata


def _mcap(path: Path) -> bool:
    head = _head(path, 4096)
    if not head.startswith(_MCAP_MAGIC) or len(head) < 8 + 9 + 4 or head[8] != 0x01:  # Header record
        return False
    (profile_len,) = struct.unpack_from("<I", head, 17)
    at = 21 + profile_len
    if len(head) < at + 4:
        return False
    (library_len,) = struct.unpack_from("<I", head, at)
    return head[at + 4 : at + 4 + library_len].decode("utf-8", "replace").startswith(MARK)


def _bag(path: Path) -> bool:
    from rosbags.highlevel import AnyReader  # heavy: only when a bag is in the way

    try:
        with AnyReader([path]) as reader:
            return any(c.topic == f"/{MARK}/metadata" for c in reader.connections)
    except Exception:  # any bag rosbags cannot open is not one lanecast wrote
        return False


def _json(path: Path) -> bool:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    if not isinstance(doc, dict):
        return False
    meta = doc.get("meta")
    marks = [
        doc.get("generator"),
        doc.get("format"),
        meta.get("generator") if isinstance(meta, dict) else None,
    ]
    return any(str(mark).startswith(MARK) for mark in marks if mark is not None)


def _png(path: Path) -> bool:
    head = _head(path, 4096)
    return head.startswith(b"\x89PNG") and b"Software\x00" + MARK.encode() in head


def _card(path: Path) -> bool:
    """Weights (``.safetensors``, ``.onnx``) are lanecast's if the model card beside them is."""
    card = path.with_suffix(".json")
    return card.is_file() and _json(card)


def lanecast_wrote(path: Path) -> bool:
    """True if the existing file or ROS 2 bag directory ``path`` is an output of lanecast's (or empty)."""
    if path.is_dir():
        metadata = path / "metadata.yaml"
        return metadata.is_file() and (MARK in metadata.read_text(encoding="utf-8", errors="replace"))
    if path.stat().st_size == 0:
        return True
    suffix = path.suffix.lower()
    if suffix == ".html":
        return HTML_MARK.encode() in _head(path)
    if suffix == ".md":
        return _head(path, 64).decode("utf-8", "replace").startswith(MARKDOWN_MARK)
    readers = {
        ".parquet": _parquet,
        ".mcap": _mcap,
        ".bag": _bag,
        ".json": _json,
        ".png": _png,
        ".safetensors": _card,
        ".onnx": _card,
    }
    if suffix in readers:
        return readers[suffix](path)
    head = _head(path, 16)
    if head.startswith(b"PAR1"):
        return _parquet(path)
    if head.startswith(_MCAP_MAGIC):
        return _mcap(path)
    return False


def check_replaceable_output(path: Path, *, force: bool = False) -> None:
    """OutputError unless ``path`` is free, an output of lanecast's, or ``force`` is set."""
    if force or not (path.exists() or path.is_symlink()) or lanecast_wrote(path):
        return
    raise OutputError(
        path,
        "exists and is not an output of lanecast's, so it is not replaced",
        expected="a new --out, or --force to replace it",
    )


def check_replaceable_files(directory: Path, names: tuple[str, ...], *, force: bool = False) -> None:
    """:func:`check_replaceable_output` for each of the files ``names`` a command writes into ``directory``."""
    for name in names:
        check_replaceable_output(directory / name, force=force)
