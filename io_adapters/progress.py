"""Progress bars for long work: tqdm on stderr, shown on a terminal, silent in pipes and CI."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import TypeVar

from tqdm.auto import tqdm

T = TypeVar("T")


def progress(iterable: Iterable[T], *, desc: str, total: int | None = None, unit: str = "it") -> Iterator[T]:
    """Wrap ``iterable`` in a progress bar (disabled when stderr is not a terminal)."""
    yield from tqdm(
        iterable, desc=desc, total=total, unit=unit, disable=None, dynamic_ncols=True, leave=False
    )


def bar(*, desc: str, total: int | float | None = None, unit: str = "it") -> tqdm:
    """A manual progress bar (``update(n)``), disabled when stderr is not a terminal."""
    return tqdm(desc=desc, total=total, unit=unit, disable=None, dynamic_ncols=True, leave=False)
