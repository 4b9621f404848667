"""The errors a damaged MCAP file raises, by what is wrong with it.

All are :class:`~lanecast.io_adapters.errors.LogError`: the CLI prints them as one line naming the
file, the byte offset and what was expected. The kind says what to do about it: a truncated file
lost its end (``--salvage`` reads what is there), a corrupt record or a CRC mismatch is damage in
place, an index mismatch means the summary or indexes disagree with the data section (``mcap
recover`` writes them anew).
"""

from __future__ import annotations

from lanecast.io_adapters.errors import LogError


class McapError(LogError):
    """An MCAP file that cannot be read as one."""


class NotMcap(McapError):
    """A file that does not start with the MCAP magic (or is empty)."""


class TruncatedFile(McapError):
    """A file that ends inside a record, or before its footer and closing magic."""


class CorruptRecord(McapError):
    """A record whose fields do not fit it, of an invalid opcode, or that uses an undefined id."""


class CrcMismatch(McapError):
    """A chunk, the data section or the summary whose CRC is not the one stored."""


class IndexMismatch(McapError):
    """A summary or index record that disagrees with the data section."""


class LogDamage(Exception):
    """Damage the walk found (internal): raised as an :class:`McapError` of kind ``kind``, or with
    salvage recorded and skipped (``resync``: the walk looks for the next intact chunk)."""

    def __init__(
        self, offset: int, message: str, expected: str, resync: bool, kind: type[McapError] = CorruptRecord
    ) -> None:
        super().__init__(message)
        self.offset, self.message, self.expected, self.resync, self.kind = (
            offset,
            message,
            expected,
            resync,
            kind,
        )

    def error(self, path: object) -> McapError:
        return self.kind(str(path), self.message, offset=self.offset, expected=self.expected)
