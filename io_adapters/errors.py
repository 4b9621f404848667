"""lanecast's own exception types.

Every error a user can cause with bad input is one of these, and its message names the file, the
row or byte offset, the column or topic, and what was expected, so that it can be fixed without a
debugger. The CLI prints them as one line and exits with status 2; nothing else is caught.
"""

from __future__ import annotations

from pathlib import Path


class LanecastError(Exception):
    """Base class of every error lanecast raises on purpose."""


class InputError(LanecastError):
    """Input that cannot be read as what it claims to be.

    ``line`` is 1-based and counts the header line, as an editor shows it; ``offset`` is a byte
    offset for binary files (logs). Either may be None where it does not apply.
    """

    def __init__(
        self,
        path: str | Path | None,
        message: str,
        *,
        line: int | None = None,
        offset: int | None = None,
        column: str | None = None,
        expected: str | None = None,
    ) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        self.offset = offset
        self.column = column
        self.expected = expected
        message = " ".join(str(message).split())  # one line, whatever a library's message holds
        self.reason = message
        where = [self.path] if self.path is not None else []
        if line is not None:
            where.append(f"line {line}")
        if offset is not None:
            where.append(f"offset {offset}")
        if column is not None:
            where.append(f"column {column!r}")
        text = ", ".join(where) + f": {message}" if where else message  # no "<input>: " for an option
        if expected is not None:
            text += f" (expected {expected})"
        super().__init__(text)

    def naming(self, path: str | Path) -> InputError:
        """This error, naming ``path`` if it names no file (a check of data a command read from
        ``path``, made by code that never saw the path)."""
        if self.path is not None:
            return self
        return type(self)(
            path, self.reason, line=self.line, offset=self.offset, column=self.column, expected=self.expected
        )

    def __reduce__(self) -> tuple[object, ...]:
        # Picklable across worker processes (bulk runs), keyword arguments included.
        return (
            _rebuild,
            (type(self), self.path, self.reason, self.line, self.offset, self.column, self.expected),
        )


def _rebuild(
    cls: type[InputError],
    path: str | None,
    reason: str,
    line: int | None,
    offset: int | None,
    column: str | None,
    expected: str | None,
) -> InputError:
    return cls(path, reason, line=line, offset=offset, column=column, expected=expected)


class OutputError(InputError):
    """An output path lanecast cannot write (a directory, a read-only place, a symlink loop)."""


class FormatNotRecognisedError(InputError):
    """No adapter recognises the file."""


class TrackTableError(LanecastError):
    """A track table that breaks the contract of docs/design.md §1 (see lanecast.io_adapters.contracts.track_table)."""


class LogError(InputError):
    """A drive log (MCAP or bag) that is damaged, empty, or has no supported topic."""


class FrameError(LanecastError):
    """Objects in a moving frame with no transform to a fixed frame in the log."""


class UsageError(LanecastError):
    """An option the command cannot work with as given (a Ray address nobody answers at, …): the
    message names the option, the value and what was expected."""

    def __init__(self, option: str, message: str, expected: str | None = None) -> None:
        self.option = option
        self.reason = message
        self.expected = expected
        text = f"{option}: {message}"
        if expected is not None:
            text += f" (expected {expected})"
        super().__init__(text)

    def __reduce__(self) -> tuple[object, ...]:
        return (UsageError, (self.option, self.reason, self.expected))
