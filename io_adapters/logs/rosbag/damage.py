"""Where a ROS 2 bag's sqlite3 file that rosbags cannot read is damaged, which rosbags does not say.

rosbags says "database disk image is malformed" for a cut sqlite3 file. After such a failure
(never on the happy path) :func:`sqlite_damage` names the offset of the first thing that is wrong:
the database header's page size and page count against the file's size, else the first page
sqlite's own check finds damaged. (A ROS 1 bag's records: :mod:`ros1_damage`; MCAP storage: the
checked MCAP walk.)

A message whose bytes cannot be decoded is found in the storage file by its bytes
(:func:`message_offset`: sqlite3 keeps the first few hundred bytes of every row on its page).
"""

from __future__ import annotations

import mmap
import re
import struct
from pathlib import Path

SQLITE_MAGIC = b"SQLite format 3\x00"


def short_error(exc: Exception) -> str:
    """An exception of another library as one line of at most 160 characters."""
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text if len(text) <= 160 else text[:157] + "..."


def sqlite_damage(path: Path) -> tuple[int, str] | None:
    """(offset, what is wrong) of a sqlite3 file cut short (:func:`sqlite_truncation`) or whose
    b-trees sqlite's own check finds damaged, or None."""
    found = sqlite_truncation(path)
    if found is not None:
        return found
    with open(path, "rb") as f:
        (page_size,) = struct.unpack_from(">H", f.read(18), 16)  # a complete header: see above
    return _integrity(path, 65536 if page_size == 1 else page_size)


def sqlite_truncation(path: Path) -> tuple[int, str] | None:
    """(offset, what is wrong) of a sqlite3 file whose header does not match its size, or None:
    cheap (100 bytes and a seek), so checked before reading, where a file cut by a few bytes may
    still open."""
    with open(path, "rb") as f:
        head = f.read(100)
        size = f.seek(0, 2)
    if len(head) < 100:
        return len(head), f"the file is truncated: {size} bytes, inside the 100-byte sqlite3 header"
    if not head.startswith(SQLITE_MAGIC):
        return 0, "no sqlite3 header (SQLite format 3)"
    (page_size,) = struct.unpack_from(">H", head, 16)
    page_size = 65536 if page_size == 1 else page_size
    (pages,) = struct.unpack_from(">I", head, 28)
    valid = head[24:28] == head[92:96]  # the page count is valid only where these agree
    if valid and pages and size < pages * page_size:
        return size, (
            f"the file is truncated: its header declares {pages} pages of {page_size} bytes "
            f"({pages * page_size} bytes), the file ends at {size}"
        )
    return None


def _integrity(path: Path, page_size: int) -> tuple[int, str] | None:
    """sqlite's own check of the b-trees (read-only): the first damaged page it names, as an offset."""
    import sqlite3

    try:
        con = sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True)
        try:
            rows = con.execute("PRAGMA quick_check(1)").fetchall()
        finally:
            con.close()
    except sqlite3.Error as exc:
        return 0, f"not a readable sqlite3 database: {exc}"
    report = " ".join(str(r[0]) for r in rows).replace("*** in database main ***", "").strip()
    if report in ("", "ok"):
        return None
    page = re.search(r"[Pp]age (\d+)", report)
    offset = (int(page.group(1)) - 1) * page_size if page else 0
    return offset, f"damaged sqlite3 database: {' '.join(report.split())}"


#: Bytes of a message searched for: fewer than a sqlite3 row keeps on its own page (at least
#: 489 of a 4096-byte page's payload), enough to tell two messages of one time and topic apart.
_NEEDLE = 256


def message_offset(path: Path, raw: object) -> int | None:
    """The byte offset in ``path`` of the message whose bytes are ``raw``, where they are there
    once (stored uncompressed), else None."""
    if not isinstance(raw, (bytes, bytearray, memoryview)) or len(raw) < 8:
        return None
    needle = bytes(raw[:_NEEDLE])
    with open(path, "rb") as f:
        if f.seek(0, 2) < len(needle):
            return None
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            at = mm.find(needle)
            if at < 0 or mm.find(needle, at + 1) >= 0:
                return None
            return at


def sqlite_page(path: Path, offset: int) -> int | None:
    """The 1-based page of a sqlite3 file that holds byte ``offset``, or None."""
    with open(path, "rb") as f:
        head = f.read(18)
    if len(head) < 18 or not head.startswith(SQLITE_MAGIC):
        return None
    (page_size,) = struct.unpack_from(">H", head, 16)
    return offset // (65536 if page_size == 1 else page_size) + 1
