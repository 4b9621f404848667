"""Files lanecast reads and writes.

Atomic outputs: a reader never sees half of one. Outputs are written under a temporary name beside the target and renamed into place only when
complete; on any error the temporary is removed and an existing target is left untouched.

Paths: :func:`check_input` is the one place that decides whether a path may be opened as an input
(a regular file or a directory, readable; never a FIFO, device or symlink loop, which would block
or crash a sniffer), :func:`check_output` whether an output path can be written.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from fnmatch import fnmatch
from pathlib import Path

from lanecast.io_adapters.errors import InputError, OutputError
from lanecast.io_adapters.ownership import check_replaceable_output


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


NOT_REGULAR = "not a regular file (a FIFO, socket or device)"
#: suffixes of compressed copies of a data file (trajectories-0400-0415.txt.gz): read by no reader,
#: named in the error where the file itself is looked for
COMPRESSED_SUFFIXES = (".gz", ".bz2", ".xz", ".zst", ".zip")


def not_regular(path: Path) -> str | None:
    """Why ``path``, an entry a reader found in an input directory, is no file it may open: a FIFO,
    socket or device (opening it would block, or read forever), a symbolic link to nothing, a link
    loop; None for a regular file or a directory. Only ``stat``: nothing is opened."""
    try:
        info = os.stat(path)
    except FileNotFoundError:
        return "a symbolic link to a missing file" if path.is_symlink() else None  # gone since listed
    except OSError as exc:
        return f"cannot open: {exc.strerror or exc}"
    if stat.S_ISREG(info.st_mode) or stat.S_ISDIR(info.st_mode):
        return None
    return NOT_REGULAR


def check_input(path: str | Path) -> Path:
    """``path`` as a Path if it is a readable regular file or directory; InputError otherwise.

    Looks with ``stat`` before anything opens the path: opening a FIFO would block, and a symlink
    loop or an unreadable file must be refused with the file's name, not a traceback.
    """
    path = Path(path)
    try:
        info = os.stat(path)
    except FileNotFoundError as exc:
        raise InputError(path, "no such file or directory") from exc
    except OSError as exc:  # ELOOP, EACCES on a parent, ENAMETOOLONG, …
        raise InputError(path, f"cannot open: {exc.strerror or exc}") from exc
    try:
        if stat.S_ISDIR(info.st_mode):
            os.listdir(path)
        elif stat.S_ISREG(info.st_mode):
            with open(path, "rb") as fh:
                fh.read(1)
        else:
            raise InputError(path, NOT_REGULAR, expected="a file or a directory")
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from exc
    return path


def check_output(path: str | Path, *, directory: bool = False) -> Path:
    """``path`` as a Path if lanecast can write an output there; OutputError otherwise.

    Refused: an existing directory where a file is wanted (or a file where a directory is wanted),
    a device, FIFO or socket, a symlink loop, a parent that is not a directory or cannot be written.
    """
    path = Path(path)
    try:
        info: os.stat_result | None = os.stat(path)
    except FileNotFoundError:
        info = None
    except OSError as exc:
        raise OutputError(path, f"cannot write here: {exc.strerror or exc}") from exc
    if info is not None:
        if not (stat.S_ISDIR(info.st_mode) or stat.S_ISREG(info.st_mode)):
            # renaming the output onto it would replace a device node (/dev/null, as root) or a FIFO
            raise OutputError(
                path, "not a regular file (a device, FIFO or socket)", expected="a file or directory path"
            )
        if not directory and stat.S_ISDIR(info.st_mode):
            raise OutputError(path, "is a directory", expected="a file path for the output")
        if directory and not stat.S_ISDIR(info.st_mode):
            raise OutputError(path, "exists and is not a directory", expected="an output directory")
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    try:
        parent_info = os.stat(parent)
    except OSError as exc:
        raise OutputError(path, f"cannot write here: {exc.strerror or exc}") from exc
    if not stat.S_ISDIR(parent_info.st_mode):
        raise OutputError(path, f"{parent} is not a directory", expected="an output path in a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(
            path,
            f"the directory {parent} is not writable",
            expected="an --out in a directory you can write to",
        )
    return path


def first_of(names: list[str]) -> str:
    """The first of ``names`` (quoted) and how many more: "'a.csv' and 2 more"."""
    return f"{names[0]!r}" + (f" and {len(names) - 1} more" if len(names) > 1 else "")


#: ``replaces`` of a directory output replaced whatever its files (``--force``)
ANY_FILES: tuple[str, ...] = ("*",)


def check_replaceable(target: Path, replaces: tuple[str, ...] = ()) -> None:
    """OutputError if the existing directory ``target`` holds an entry matching none of the name
    patterns ``replaces`` (a user's file, which replacing the directory would delete).

    Even with :data:`ANY_FILES` (``--force``) a directory holding folders, the working directory,
    one of its parents or the home directory is refused: --force replaces files, not a tree."""
    if not target.is_dir() or target.is_symlink():
        return
    if replaces == ANY_FILES:
        resolved = target.resolve()
        if resolved == Path.home().resolve() or resolved in (
            Path.cwd().resolve(),
            *Path.cwd().resolve().parents,
        ):
            raise OutputError(
                target,
                "is the working directory, one of its parents or the home directory",
                expected="a directory of its own for the output, even with --force",
            )
        folders = sorted(p.name for p in target.iterdir() if p.is_dir() and not p.is_symlink())
        if folders:
            raise OutputError(
                target,
                f"the directory holds the folder {first_of(folders)}, which --force does not delete",
                expected="a new or empty directory, or one holding only files",
            )
        return
    foreign = sorted(p.name for p in target.iterdir() if not any(fnmatch(p.name, r) for r in replaces))
    if foreign:
        raise OutputError(
            target,
            f"the directory holds {first_of(foreign)}, which this output would delete",
            expected="a new or empty directory, or a previous output of the same command",
        )


def check_output_dir(
    path: str | Path,
    *,
    files: tuple[str, ...] = (),
    replaces: tuple[str, ...] | None = None,
    force: bool = False,
) -> Path:
    """What a command that writes the directory ``path`` checks before any work (an output it cannot
    write was refused only after minutes of training or cutting): :func:`check_output`, none of the
    ``files`` it writes into the directory is a directory or a file lanecast did not write (unless
    ``force``), and, for a directory replaced as a whole (``replaces`` given, as for
    :func:`atomic_path`), nothing else is in it."""
    path = check_output(path, directory=True)
    for name in files:
        final = path / name
        if final.is_dir() and not final.is_symlink():
            raise OutputError(final, "is a directory", expected="a file lanecast may replace")
        check_replaceable_output(final, force=force)
    if replaces is not None:
        check_replaceable(path, replaces)
    return path


@contextlib.contextmanager
def atomic_path(
    target: str | Path, *, directory: bool = False, replaces: tuple[str, ...] = ()
) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success.

    An existing ``target`` directory is replaced only if every entry in it matches one of the
    name patterns ``replaces`` (what this kind of output holds: a previous run's output): a
    directory with anything else in it (a user's files) is refused, never deleted."""
    target = check_output(target, directory=directory)
    if directory:
        check_replaceable(target, replaces)
    prefix = f".{target.name}.tmp-"
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        if directory:
            tmp = Path(tempfile.mkdtemp(prefix=prefix, dir=target.parent))
        else:
            fd, name = tempfile.mkstemp(prefix=prefix, dir=target.parent)
            os.close(fd)
            tmp = Path(name)
    except OSError as exc:
        raise OutputError(target, f"cannot write here: {exc.strerror or exc}") from exc
    # mkstemp/mkdtemp make owner-only entries; outputs get the modes of ordinary new files.
    tmp.chmod((0o777 if directory else 0o666) & ~_umask())
    try:
        yield tmp
        if target.is_symlink():  # replace a link itself, never what it points to
            target.unlink()
        elif directory and target.exists():
            shutil.rmtree(target)
        os.replace(tmp, target)
    except BaseException:
        if tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def staged_files(target: str | Path, *, force: bool = False) -> Iterator[Path]:
    """Yield a temporary directory beside the output directory ``target`` for a command's files
    (a report: metrics.json, report.html, pictures); on success move them into ``target`` (created
    if missing; files of the same names replaced if lanecast wrote them or ``force``, others left
    alone), on any error or interruption remove them: ``target`` gets all of a run's files or none."""
    target = check_output(target, directory=True)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    except OSError as exc:
        raise OutputError(target, f"cannot write here: {exc.strerror or exc}") from exc
    try:
        yield stage
        files = sorted(p for p in stage.rglob("*") if not p.is_dir())
        for path in files:  # checked before any is moved: all or none
            final = target / path.relative_to(stage)
            if final.is_dir() and not final.is_symlink():
                raise OutputError(final, "is a directory", expected="a file lanecast may replace")
            check_replaceable_output(final, force=force)
        for path in files:
            final = target / path.relative_to(stage)
            final.parent.mkdir(parents=True, exist_ok=True)
            os.replace(path, final)
            final.chmod(0o666 & ~_umask())  # mkdtemp's owner-only mode is not the outputs'
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def checksum(path: Path) -> str:
    """sha256 of a file, or of a directory's files (relative names and contents, in sorted order)."""
    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        if path.is_dir():
            h.update(str(f.relative_to(path)).encode() + b"\0")
        with open(f, "rb") as fh:
            while block := fh.read(1 << 20):
                h.update(block)
    return h.hexdigest()
