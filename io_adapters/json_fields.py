"""Typed, range-checked reading of JSON documents that come from files (metadata, model cards).

A document read from a file is input like a CSV cell: every field is checked for type and range
before use, and a bad one is reported by its dotted name (``recordings.r0.frame_rate``). The
functions here raise :class:`FieldError`; each caller turns it into its own error naming the file
(see :func:`as_input_error`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lanecast.io_adapters.errors import InputError

INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1
MAX_DEPTH = 64  # nesting accepted in a document (lanecast's own are 4 deep)


class FieldError(ValueError):
    """A field of a JSON document with the wrong type, range, or missing."""

    def __init__(self, name: str, reason: str, expected: str) -> None:
        super().__init__(f"field {name!r}: {reason} (expected {expected})")
        self.name, self.reason, self.expected = name, reason, expected


def as_input_error(path: str | Path | None, what: str, exc: FieldError) -> InputError:
    """The InputError naming ``path`` for a bad field of its ``what`` document."""
    return InputError(path, f"{what}: {exc.reason}", column=exc.name, expected=exc.expected)


def loads(text: str | bytes, name: str = "document") -> Any:
    """Parse JSON text; FieldError if it is not JSON or nests deeper than :data:`MAX_DEPTH`. A
    UTF-8 byte order mark (Windows editors write one) is no part of the document."""
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise FieldError(name, f"not UTF-8 ({exc.reason} at byte {exc.start})", "UTF-8 JSON") from exc
    text = text.removeprefix("\ufeff")
    depth = _max_depth(text)
    if depth > MAX_DEPTH:
        raise FieldError(name, f"nested {depth} levels deep", f"at most {MAX_DEPTH} levels")
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise FieldError(name, f"not JSON: {exc}", "a JSON document") from exc


def _max_depth(text: str) -> int:
    """Greatest bracket nesting of ``text`` (brackets inside strings counted too: an upper bound)."""
    depth = deepest = 0
    for ch in text:
        if ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    return deepest


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


_MISSING = object()


def get(doc: Mapping[str, Any], key: str, parent: str, kind: str, default: Any = _MISSING) -> Any:
    """``doc[key]`` checked to be of ``kind``; ``default`` where absent (else FieldError).

    Kinds: ``object``, ``str``, ``int`` (int64, not bool), ``count`` (int >= 0), ``positive_int``,
    ``number`` (finite, not bool), ``positive`` (finite > 0), ``bool``, ``str_list``, ``int_list``,
    ``number_list`` (finite); ``…|null`` also accepts None.
    """
    name = f"{parent}.{key}" if parent else key
    if key not in doc:
        if default is _MISSING:
            raise FieldError(name, "missing", f"a {kind.replace('_', ' ')}")
        return default
    return check(doc[key], name, kind)


def check(value: Any, name: str, kind: str) -> Any:
    """``value`` if it is of ``kind`` (see :func:`get`), else FieldError naming ``name``."""
    if kind.endswith("|null"):
        if value is None:
            return None
        kind = kind[: -len("|null")]
    ok = _CHECKS[kind](value)
    if not ok:
        raise FieldError(name, f"{_show(value)}", _EXPECTED[kind])
    return value


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and INT64_MIN <= v <= INT64_MAX


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def check_int(value: Any, low: int, high: int) -> bool:
    """``value`` is an integer (not bool) from ``low`` to ``high``."""
    return _is_int(value) and low <= value <= high


_CHECKS = {
    "object": lambda v: isinstance(v, dict),
    "list": lambda v: isinstance(v, list),
    "str": lambda v: isinstance(v, str),
    "int": _is_int,
    "count": lambda v: _is_int(v) and v >= 0,
    "positive_int": lambda v: _is_int(v) and v > 0,
    "number": _is_number,
    "positive": lambda v: _is_number(v) and v > 0,
    "bool": lambda v: isinstance(v, bool),
    "str_list": lambda v: isinstance(v, list) and all(isinstance(x, str) for x in v),
    "int_list": lambda v: isinstance(v, list) and all(_is_int(x) for x in v),
    "number_list": lambda v: isinstance(v, list) and all(_is_number(x) for x in v),
}
_EXPECTED = {
    "object": "a JSON object",
    "list": "a list",
    "str": "a string",
    "int": "an integer",
    "count": "an integer >= 0",
    "positive_int": "an integer > 0",
    "number": "a finite number",
    "positive": "a finite number > 0",
    "bool": "true or false",
    "str_list": "a list of strings",
    "int_list": "a list of integers",
    "number_list": "a list of finite numbers",
}
