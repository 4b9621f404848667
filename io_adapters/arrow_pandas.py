"""pyarrow without pandas until pandas is used: a command's process does not pay pandas' import.

pyarrow imports pandas, if installed, the first time it converts anything (``pa.array`` asks whether
its input is a pandas object; a copying ``to_numpy`` sets up pandas' own types), then uses it only
for pandas objects: 0.2–0.5 s of a command such as ``lanecast info`` or ``windows`` that never
touches one. After :func:`defer` (called by the command line, for its own process only), an import
of pandas made for lanecast's or pyarrow's own code finds none: pyarrow then converts to and from
numpy as it does without pandas installed. lanecast's code that uses pandas calls :func:`allow`
first: pandas imports, and pyarrow knows it again (a pandas categorical given to ``pa.array``
becomes a dictionary array, not strings). Other libraries import pandas as usual.

A library user's process is left alone: only the command line calls :func:`defer`.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence
    from importlib.machinery import ModuleSpec
    from types import FrameType, ModuleType

#: the packages whose imports of pandas are refused while deferred (pyarrow's compiled code has no
#: frame: its import shows as one made by the Python code that called it)
DEFERRING = ("lanecast", "pyarrow")


def _importer() -> str:
    """The module whose code is importing (the first frame outside the import machinery)."""
    frame: FrameType | None = sys._getframe(2)
    while frame is not None and frame.f_globals.get("__name__", "").startswith(("importlib", "_frozen")):
        frame = frame.f_back
    return "" if frame is None else str(frame.f_globals.get("__name__", ""))


class _PandasDeferred:
    """A meta path finder: no pandas for lanecast's and pyarrow's own imports of it."""

    refused = False

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> ModuleSpec | None:
        if fullname != "pandas" or _importer().split(".")[0] not in DEFERRING:
            return None
        _PandasDeferred.refused = True
        raise ModuleNotFoundError("pandas is imported once lanecast uses it", name="pandas")


_FINDER = _PandasDeferred()


def deferred() -> bool:
    """Whether pandas is deferred in this process."""
    return _FINDER in sys.meta_path


def defer() -> None:
    """Defer pandas in this process (no-op if it is imported already)."""
    if "pandas" not in sys.modules and not deferred():
        sys.meta_path.insert(0, _FINDER)


def allow() -> None:
    """Before lanecast uses pandas: pandas imports, and pyarrow knows it again."""
    if deferred():
        sys.meta_path.remove(_FINDER)
    if _PandasDeferred.refused:
        import pyarrow as pa

        pa.table({}).to_pandas()  # a conversion to pandas makes pyarrow look for it once more
        _PandasDeferred.refused = False
