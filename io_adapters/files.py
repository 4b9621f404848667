"""Files lanecast writes and the progress it shows while working.

Atomic outputs: a reader never sees half of one. Outputs are written under a temporary name beside the target and renamed into place only when
complete; on any error the temporary is removed and an existing target is left untouched.

Progress bars: tqdm on stderr, shown on a terminal, silent in pipes and CI.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TypeVar

from tqdm.auto import tqdm

T = TypeVar("T")


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


def progress(iterable: Iterable[T], *, desc: str, total: int | None = None, unit: str = "it") -> Iterator[T]:
    """Wrap ``iterable`` in a progress bar (disabled when stderr is not a terminal)."""
    yield from tqdm(
        iterable, desc=desc, total=total, unit=unit, disable=None, dynamic_ncols=True, leave=False
    )


def bar(*, desc: str, total: int | float | None = None, unit: str = "it") -> tqdm:
    """A manual progress bar (``update(n)``), disabled when stderr is not a terminal."""
    return tqdm(desc=desc, total=total, unit=unit, disable=None, dynamic_ncols=True, leave=False)
