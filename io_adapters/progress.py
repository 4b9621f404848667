"""The progress lanecast shows on stderr while it works.

On a terminal: a bar, redrawn at most every ``REDRAW_S`` and cleared when the work ends. Anywhere
else (a pipe, a log file, CI): a plain line when the work starts, one every ``LINE_INTERVAL_S`` and
one at the end, so that long work in a batch job still shows that it moves, without carriage
returns or bar characters in the log.

lanecast's own rather than tqdm's: importing tqdm (with importlib.metadata and logging) took
0.03–0.06 s, a tenth of a small command's whole run, and lanecast uses a few of its features.
The lines read as tqdm's do: ``convert: 3/10 piece (30%) [00:05<00:11, 0.60piece/s]``.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from types import TracebackType
from typing import IO, Any, TypeVar

T = TypeVar("T")

LINE_INTERVAL_S = 5.0  # seconds between two progress lines when stderr is not a terminal
REDRAW_S = 0.1  # seconds between two redraws of a terminal's bar
LINE_FORMAT = (
    "{desc}: {n_fmt}/{total_fmt} {unit} ({percentage:.0f}%) [{elapsed}<{remaining}, {rate_fmt}{postfix}]"
)
LINE_FORMAT_NO_TOTAL = "{desc}: {n_fmt} {unit} [{elapsed}, {rate_fmt}{postfix}]"
BAR_FORMAT = (
    "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}, {rate_fmt}{postfix}]"
)
BAR_FORMAT_NO_TOTAL = "{desc}: {n_fmt}{unit} [{elapsed}, {rate_fmt}{postfix}]"
DEFAULT_COLUMNS = 80  # a terminal that does not say its width (``script -qc``)


def format_interval(seconds: float) -> str:
    """``MM:SS``, or ``H:MM:SS`` from an hour on."""
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours:d}:{minutes:02d}:{secs:02d}" if hours else f"{minutes:02d}:{secs:02d}"


def _count(n: float) -> str:
    return str(int(n)) if float(n).is_integer() else f"{n:g}"


def _rate(n: float, elapsed: float, unit: str) -> tuple[str, float | None]:
    """The rate as shown (``12.50piece/s``, or ``4.00s/piece`` when slower than one a second, ``?``
    before the first step) and the rate itself."""
    if n <= 0 or elapsed <= 0:
        return f"?{unit}/s", None
    rate = n / elapsed
    if rate < 1:
        return f"{1 / rate:5.2f}s/{unit}", rate
    return f"{rate:5.2f}{unit}/s", rate


def terminal_columns(stream: IO[str]) -> int:
    """The width of the terminal ``stream`` writes to; 0 where it does not say."""
    try:
        return os.get_terminal_size(stream.fileno()).columns
    except (OSError, ValueError, AttributeError):
        return 0


class Progress:
    """A count of work done, shown on ``file`` (stderr): ``update(n)`` as work is done, ``close()``
    (or a ``with`` block) when it ends. ``disable``: counts, shows nothing. Safe to update from
    another thread (an activity's ticker)."""

    def __init__(
        self,
        *,
        desc: str,
        total: float | None = None,
        unit: str = "it",
        bar_format: str | None = None,
        disable: bool = False,
        file: IO[str] | None = None,
    ) -> None:
        self.desc, self.total, self.unit = desc, total or None, unit
        self.file = sys.stderr if file is None else file
        self.disable = disable
        self.n: float = 0
        self.postfix = ""
        self.final_line = True  # False: close without the last count (the work stopped on an error)
        self.terminal = _isatty(self.file)
        self._bar_format = bar_format
        self._started = time.monotonic()
        self._shown_at = -float("inf")
        self._shown_n: float | None = None
        self._drawn = False
        self._closed = False
        self._lock = threading.Lock()
        if not disable:
            with self._lock:
                self._show(time.monotonic())

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def update(self, n: float = 1) -> None:
        """``n`` more done; shown if the last showing is old enough."""
        with self._lock:
            self.n += n
            if self.disable or self._closed:
                return
            now = time.monotonic()
            if now - self._shown_at >= (REDRAW_S if self.terminal else LINE_INTERVAL_S):
                self._show(now)

    def set_postfix(self, **values: Any) -> None:
        """``key=value`` pairs after the rate (shown with the next count, never on their own)."""
        self.postfix = ", ".join(f"{k}={v}" for k, v in values.items())

    def set_postfix_str(self, text: str = "") -> None:
        """Text after the rate (shown with the next count, never on their own)."""
        self.postfix = text

    def write(self, message: str) -> None:
        """Print ``message`` on stdout; a terminal's bar is cleared first and drawn again after it."""
        with self._lock:
            if self._drawn:
                self._clear()
            print(message, file=sys.stdout, flush=True)
            if self.terminal and not (self.disable or self._closed):
                self._show(time.monotonic())

    def close(self) -> None:
        """The end: a terminal's bar is cleared; a log gets the last count unless it has it or
        :attr:`final_line` is False."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            if self.disable:
                return
            if self.terminal:
                if self._drawn:
                    self._clear()
            elif self.final_line and self._shown_n != self.n:
                self._show(time.monotonic())

    def text(self, now: float | None = None, columns: int = 0) -> str:
        """What is shown now: a line, or (``columns`` > 0) a terminal's bar that fits them."""
        elapsed = (time.monotonic() if now is None else now) - self._started
        rate_fmt, rate = _rate(self.n, elapsed, self.unit)
        fields: dict[str, Any] = {
            "desc": self.desc,
            "unit": self.unit,
            "n_fmt": _count(self.n),
            "elapsed": format_interval(elapsed),
            "rate_fmt": rate_fmt,
            "postfix": f", {self.postfix}" if self.postfix else "",
            "bar": "{bar}",
        }
        if self.total:
            left = max(self.total - self.n, 0)
            fields |= {
                "total_fmt": _count(self.total),
                "percentage": 100.0 * min(self.n / self.total, 1.0),
                "remaining": format_interval(left / rate) if rate else "?",
            }
        if self._bar_format is not None:
            template = self._bar_format
        elif columns:
            template = BAR_FORMAT if self.total else BAR_FORMAT_NO_TOTAL
        else:
            template = LINE_FORMAT if self.total else LINE_FORMAT_NO_TOTAL
        line = template.format(**fields)
        if "{bar}" in line:
            width = max(columns - len(line) + len("{bar}") - 1, 1)
            filled = round(width * fields["percentage"] / 100.0)
            line = line.replace("{bar}", "█" * filled + " " * (width - filled))
        return line[: columns - 1] if columns > 1 else line

    def _show(self, now: float) -> None:
        """Draw (terminal) or print (log) the count; the caller holds the lock."""
        self._shown_at, self._shown_n = now, self.n
        if self.terminal:
            columns = terminal_columns(self.file) or DEFAULT_COLUMNS
            self.file.write("\r" + self.text(now, columns) + "\x1b[K")
            self._drawn = True
        else:
            self.file.write(self.text(now).strip() + "\n")
        self.file.flush()

    def _clear(self) -> None:
        self.file.write("\r\x1b[K")
        self.file.flush()
        self._drawn = False


def _isatty(stream: IO[str]) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


_outer_bars = 0  # bars of a whole job open in this process: the bars of its parts stay quiet


def bar(
    *, desc: str, total: float | None = None, unit: str = "it", bar_format: str | None = None
) -> Progress:
    """A manual progress bar (``update(n)``): a bar on a terminal, a line every few seconds otherwise;
    none while a :func:`job_progress` bar is open."""
    return Progress(desc=desc, total=total, unit=unit, bar_format=bar_format, disable=_outer_bars > 0)


def progress(iterable: Iterable[T], *, desc: str, total: int | None = None, unit: str = "it") -> Iterator[T]:
    """Wrap ``iterable`` in progress: a bar on a terminal, a line every few seconds otherwise."""
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    with bar(desc=desc, total=total, unit=unit) as shown:
        try:
            for item in iterable:
                yield item
                shown.update(1)
        except GeneratorExit:
            # The consumer stopped, on an error whose message may already be out: a count printed
            # now (when the abandoned generator is collected) would follow it as stderr's last line.
            shown.final_line = False
            raise


@contextlib.contextmanager
def job_progress(*, desc: str, total: int, unit: str) -> Iterator[Progress]:
    """One bar for a whole job of ``total`` parts (convert's pieces, say): the bars the parts would
    show of their own (a reader's "0/1 recording") are not shown while it is open. A job of one
    part shows that part's bars instead."""
    global _outer_bars
    if total <= 1:  # one part: its own bar says more (a reader's recordings), and nothing is doubled
        with Progress(desc=desc, total=total, unit=unit, disable=True) as silent:
            yield silent
        return
    with bar(desc=desc, total=total, unit=unit) as shown:
        _outer_bars += 1
        try:
            yield shown
        finally:
            _outer_bars -= 1


@contextlib.contextmanager
def activity(desc: str) -> Iterator[None]:
    """Life signs for a step that has no count to show (a model's export, a report's figures): on a
    terminal a line with the elapsed time, otherwise a line when it starts and every few seconds
    while it runs, so that no command stays silent for longer than that."""
    shown = bar(desc=desc, total=None, unit="s", bar_format="{desc} ({elapsed})")
    done = threading.Event()
    started = time.monotonic()

    def tick() -> None:
        while not done.wait(0.5 if shown.terminal else 1.0):
            shown.update(int(time.monotonic() - started) - shown.n)

    ticker = threading.Thread(target=tick, name=f"activity: {desc}", daemon=True)
    ticker.start()
    try:
        yield
    except BaseException:
        shown.final_line = False  # the error is the last line, not a count after it
        raise
    finally:
        done.set()
        ticker.join()
        shown.close()
