"""Files lanecast writes and the progress it shows while working.

Atomic outputs: a reader never sees half of one. Outputs are written under a temporary name beside the target and renamed into place only when
complete; on any error the temporary is removed and an existing target is left untouched.

Progress: tqdm's bars on stderr when it is a terminal; when it is not (a pipe, a log file, CI), a
plain line every few seconds (``LINE_INTERVAL_S``) and one at the end, so that long work in a batch
job still shows that it moves, without carriage returns or bar characters in the log.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from tqdm.auto import tqdm

T = TypeVar("T")

LINE_INTERVAL_S = 5.0  # seconds between two progress lines when stderr is not a terminal
LINE_FORMAT = (
    "{desc}: {n_fmt}/{total_fmt} {unit} ({percentage:.0f}%) [{elapsed}<{remaining}, {rate_fmt}{postfix}]"
)
LINE_FORMAT_NO_TOTAL = "{desc}: {n_fmt} {unit} [{elapsed}, {rate_fmt}{postfix}]"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(target: str | Path, *, directory: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    prefix = f".{target.name}.tmp-"
    if directory:
        tmp = Path(tempfile.mkdtemp(prefix=prefix, dir=target.parent))
    else:
        fd, name = tempfile.mkstemp(prefix=prefix, dir=target.parent)
        os.close(fd)
        tmp = Path(name)
    # mkstemp/mkdtemp make owner-only entries; outputs get the modes of ordinary new files.
    tmp.chmod((0o777 if directory else 0o666) & ~_umask())
    try:
        yield tmp
        if directory and target.exists():
            shutil.rmtree(target)
        os.replace(tmp, target)
    except BaseException:
        if tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            tmp.unlink(missing_ok=True)
        raise


class ProgressLines(tqdm):
    """tqdm that writes whole lines (no ``\\r``, no bar) at most every ``mininterval`` seconds, and a
    last line when it closes: progress for a stderr that is not a terminal."""

    _last_line_at = -float("inf")
    _closing = False

    def display(self, msg: str | None = None, pos: int | None = None) -> bool:  # type: ignore[override]
        if msg == "":  # tqdm clearing its line: nothing to clear in a log
            return False
        now = time.monotonic()
        if not self._closing and now - self._last_line_at < self.mininterval:
            return False  # e.g. tqdm.write restoring the bar after a message
        self._last_line_at = now
        text = self.__str__() if msg is None else msg
        self.fp.write(text.strip() + "\n")
        self.fp.flush()
        return True

    def clear(self, nolock: bool = False) -> None:
        """Lines are never erased (tqdm.write calls this before and after its message)."""

    def set_postfix(self, ordered_dict: Any = None, refresh: bool | None = True, **kwargs: Any) -> None:
        """Only the timed updates print a line: a new postfix does not force one."""
        super().set_postfix(ordered_dict, refresh=False, **kwargs)

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        super().set_postfix_str(s, refresh=False)

    def close(self) -> None:
        if not self.disable and getattr(self, "last_print_n", self.n) != self.n:
            self._closing = True
            self.display()  # the final count, unless the last line already said it
        super().close()


def _bar_kwargs(total: int | float | None) -> dict[str, Any]:
    if sys.stderr.isatty():
        return {"disable": None, "dynamic_ncols": True, "leave": False}
    return {
        "file": sys.stderr,
        "mininterval": LINE_INTERVAL_S,
        "maxinterval": max(LINE_INTERVAL_S, 10.0),
        "bar_format": LINE_FORMAT if total else LINE_FORMAT_NO_TOTAL,
        "leave": False,
    }


def progress(iterable: Iterable[T], *, desc: str, total: int | None = None, unit: str = "it") -> Iterator[T]:
    """Wrap ``iterable`` in progress: a bar on a terminal, a line every few seconds otherwise."""
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    with bar(desc=desc, total=total, unit=unit) as shown:
        for item in iterable:
            yield item
            shown.update(1)


def bar(*, desc: str, total: int | float | None = None, unit: str = "it") -> tqdm:
    """A manual progress bar (``update(n)``): a bar on a terminal, a line every few seconds otherwise."""
    cls = tqdm if sys.stderr.isatty() else ProgressLines
    return cls(desc=desc, total=total, unit=unit, **_bar_kwargs(total))
