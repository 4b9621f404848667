"""The manifest of a bulk annotation: ``OUT_DIR/manifest.jsonl``, what made each output and from what.

Append-only JSON lines, one fsync'ed entry per event, never rewritten. Every entry has:

- ``v``: the format version (``FORMAT_VERSION``);
- ``input``: the input log's absolute, resolved path (the key: the latest entry per input counts);
- ``output``: the output's path relative to the manifest's own directory (absolute if outside it),
  so that it resolves the same from any working directory and on any machine that mounts OUT_DIR;
- ``status``: ``started`` (written before the work: the output name is claimed, so that a file a
  killed run renamed into place is still known as lanecast's), then ``done`` or ``failed``;
- ``options`` and ``options_key``: what made the output (period, top-k, encoding, topic, the model's
  name and sha256, or the precomputed forecasts' sha256) and the sha256 of their canonical JSON;
- on ``done``/``failed``: ``sha256`` and ``stat`` of the input, ``output_sha256`` (done),
  ``counts``, ``error``, ``duration_s``, ``finished_at``, ``host``.

An output is reused only when the latest entry of its input is ``done`` with the same
``options_key``, the input is unchanged (same ``stat`` — size, mtime, ctime and inode, which a
``cp -p`` cannot forge — else the same sha256) and the output is still the file it recorded (inside
OUT_DIR, no symlink, the same ``output_sha256``). Everything else is redone. The manifest and the
lock are never opened through a symlink.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import stat
from pathlib import Path
from typing import Any

from lanecast.io_adapters.errors import InputError

MANIFEST = "manifest.jsonl"
FORMAT_VERSION = 2


def stat_signature(path: Path) -> list[int]:
    """[size, latest mtime_ns, latest ctime_ns, inode or file count] of a file or a directory's files.

    A cheap "unchanged" test: rewriting a file in place changes its ctime, which no copy tool can set
    back, and replacing it changes its inode."""
    path = Path(path)
    if path.is_file():
        st = path.stat()
        return [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]
    stats = [f.stat() for f in path.rglob("*") if f.is_file()]
    return [
        sum(st.st_size for st in stats),
        max((st.st_mtime_ns for st in stats), default=0),
        max((st.st_ctime_ns for st in stats), default=0),
        len(stats),
    ]


def options_key(options: dict[str, Any]) -> str:
    """sha256 of the options' canonical JSON: equal keys, equal outputs."""
    return hashlib.sha256(json.dumps(options, sort_keys=True).encode()).hexdigest()


def absolute(path: Path | str) -> Path:
    """``path`` made absolute and normalised (``..`` removed), symbolic links kept as named."""
    return Path(os.path.abspath(path))


def relative_to_manifest(output: Path, out_dir: Path) -> str:
    """``output`` as the manifest records it: relative to ``out_dir`` (the manifest's directory) when
    inside it, else absolute."""
    output = absolute(output)
    try:
        return output.relative_to(absolute(out_dir)).as_posix()
    except ValueError:
        return str(output)


def not_ours(path: Path, exc: OSError) -> InputError:
    """The error for a manifest or lock that cannot be opened as lanecast's own regular file."""
    if path.is_symlink():
        return InputError(
            path,
            "is a symlink; lanecast does not follow symlinks in its output directory",
            expected="a regular file there, not a link",
        )
    return InputError(path, f"cannot open: {exc.strerror or exc}")


def open_regular(path: Path, flags: int) -> int:
    """A descriptor of ``path`` (a manifest or lock in OUT_DIR) opened with ``flags``, never through
    a symlink and never blocking on a FIFO; InputError unless it is a regular file (a directory
    opens read-only, then fails as 'fd 4'; a FIFO would block the run for ever)."""
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
    except FileNotFoundError:
        raise
    except OSError as exc:
        with contextlib.suppress(OSError):  # a FIFO opened for writing with no reader: ENXIO
            if not stat.S_ISREG(os.lstat(path).st_mode) and not path.is_symlink():
                raise _not_regular(path) from exc
        raise not_ours(path, exc) from exc
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise _not_regular(path)
    os.set_blocking(fd, True)
    return fd


def _not_regular(path: Path) -> InputError:
    return InputError(
        path,
        "not a regular file (a directory, FIFO, socket or device)",
        expected=f"the {path.name} lanecast annotate writes, or nothing",
    )


class Manifest:
    """``OUT_DIR/manifest.jsonl``: append-only, one JSON object per line, fsync'ed per entry."""

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = Path(out_dir)
        self.path = self.out_dir / MANIFEST
        self._parsed: tuple[tuple[int, ...], list[dict[str, Any]]] | None = None

    def entries(self) -> list[dict[str, Any]]:
        """Every complete entry that is a JSON object with a string ``input`` (a line cut short by
        a kill, or one that is not an entry, is ignored; an editor's byte order mark and CRLF line
        ends are read through). An ``output`` recorded absolute but inside OUT_DIR is given as
        relative to it, as lanecast records it. The manifest itself is never followed through a
        symlink; a manifest unchanged since the last call is not parsed again."""
        try:
            fd = open_regular(self.path, os.O_RDONLY)
        except FileNotFoundError:
            return []
        info = os.fstat(fd)
        signature = (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns, info.st_ctime_ns)
        if self._parsed is not None and self._parsed[0] == signature:
            os.close(fd)
            return list(self._parsed[1])
        out = []
        with open(fd, encoding="utf-8", errors="replace") as f:
            for line in f:
                if not line.endswith("\n"):
                    continue
                # ValueError: also an integer of more digits than Python converts
                with contextlib.suppress(ValueError, RecursionError):
                    entry = json.loads(line.lstrip("\ufeff"))
                    if isinstance(entry, dict) and isinstance(entry.get("input"), str):
                        out.append(self._relative_output(entry))
        self._parsed = (signature, out)
        return list(out)

    def _relative_output(self, entry: dict[str, Any]) -> dict[str, Any]:
        recorded = entry.get("output")
        if isinstance(recorded, str) and "\0" not in recorded and os.path.isabs(recorded):
            entry["output"] = relative_to_manifest(Path(recorded), self.out_dir)
        return entry

    def latest(self) -> dict[str, dict[str, Any]]:
        """The latest entry per input path."""
        return {e["input"]: e for e in self.entries()}

    def finished(self) -> dict[str, dict[str, Any]]:
        """The latest ``done`` or ``failed`` entry per input (``started`` entries left out)."""
        return {e["input"]: e for e in self.entries() if e.get("status") in ("done", "failed")}

    def claims(self) -> dict[str, str]:
        """Output (as recorded) → the input that last claimed it, over every entry of any status."""
        return {
            e["output"]: e["input"]
            for e in self.entries()
            if isinstance(e.get("output"), str) and "\0" not in e["output"]  # no path has a NUL
        }

    def output_path(self, entry: dict[str, Any]) -> Path:
        """The output an entry names, as a path (its recorded form is relative to the manifest);
        InputError naming the manifest for an entry whose output is no file name."""
        recorded = entry.get("output")
        named = isinstance(recorded, str) and recorded.strip() != "" and "\0" not in recorded
        path = self.out_dir / str(recorded) if named else self.out_dir
        if absolute(path) == absolute(self.out_dir):  # no name, or one naming OUT_DIR itself ('.')
            raise InputError(
                self.path,
                f"the entry of {str(entry.get('input'))!r} names no output file: output {recorded!r}",
                column="output",
                expected="a path relative to the manifest's folder, as lanecast annotate writes it",
            )
        return path

    def append(self, entry: dict[str, Any]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = (json.dumps({"v": FORMAT_VERSION, **entry}, sort_keys=True) + "\n").encode()
        fd = open_regular(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
        try:
            # a line cut short by an earlier kill would swallow this entry: start on a fresh line
            size = os.fstat(fd).st_size
            if size:
                with open(self.path, "rb") as f:
                    f.seek(size - 1)
                    if f.read(1) != b"\n":
                        data = b"\n" + data
            os.write(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
