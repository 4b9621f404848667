"""Bulk annotation: many logs, a manifest, resume, local worker processes or a Ray cluster.

``OUT_DIR/manifest.jsonl`` is append-only JSON lines (each line fsync'ed): one entry per finished
attempt with the log's status (``done``/``failed``), the sha256 of the input, the output path, the
counts, the error and the duration. Paths resolve the same from any working directory: the input is
absolute, the output relative to the manifest's own directory. An entry is appended only after the output has been renamed
into place, so at any moment of a kill:

- a log whose latest entry is ``done`` with the input's current checksum and whose output exists is
  skipped by the next run; everything else (failed, never finished, changed input) is redone;
- outputs only ever appear complete (``atomic_path``); leftover ``.*.tmp-*`` entries of a killed run
  are removed when the next run starts (an exclusive lock on OUT_DIR keeps two runs apart).

Engines: ``local`` runs the per-log task in-process (1 worker) or in a ``ProcessPoolExecutor``;
``ray`` submits the same task as ``@ray.remote(max_retries=...)`` to ``--address`` or a local Ray.
On a cluster, inputs and OUT_DIR must be on storage every node sees.

Size: inputs, manifest, output-directory safety and the three engines of one bulk run; the
manifest and engines are being reworked this wave (issues 12, 13, 14), after which the manifest
is the natural module of its own.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import fcntl
import hashlib
import json
import multiprocessing as mp
import os
import queue as queue_mod
import shutil
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lanecast.io_adapters.errors import InputError, LanecastError
from lanecast.io_adapters.files import bar, check_input, checksum
from lanecast.workflows.annotate_log import AnnotateOptions, annotate_log, output_name

MANIFEST = "manifest.jsonl"
LOCK = ".lanecast-annotate.lock"
LOG_SUFFIXES = (".mcap", ".bag")


@dataclass(frozen=True)
class Task:
    """One log to annotate."""

    input: Path
    output: Path


@dataclass
class BulkResult:
    """What a bulk run did: entries written this run and the logs skipped as already done."""

    entries: list[dict[str, Any]] = field(default_factory=list)
    skipped: list[Path] = field(default_factory=list)
    out_dir: Path = Path()

    @property
    def done(self) -> list[dict[str, Any]]:
        return [e for e in self.entries if e["status"] == "done"]

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [e for e in self.entries if e["status"] == "failed"]

    def summary(self) -> str:
        lines = [
            f"annotated {len(self.done)} log(s), {len(self.failed)} failed, {len(self.skipped)} already done "
            f"-> {self.out_dir} (manifest: {self.out_dir / MANIFEST})"
        ]
        lines += [f"  FAILED {e['input']}: {e['error']}" for e in self.failed]
        return "\n".join(lines)


# ----------------------------------------------------------------------------------------- inputs


def is_ros2_bag(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def discover(paths: Sequence[Path], exclude: Path | None = None) -> list[Path]:
    """The logs named by ``paths``: files as given; directories searched recursively for ``*.mcap``,
    ``*.bag`` and ROS 2 bag directories (not descended into), skipping ``exclude`` (OUT_DIR)."""
    found: list[Path] = []
    excluded = os.path.realpath(exclude) if exclude is not None else None

    def walk(folder: Path) -> Iterator[Path]:
        for entry in sorted(folder.iterdir()):
            if excluded is not None and os.path.realpath(entry) == excluded:
                continue
            if entry.name.startswith("."):
                continue
            if is_ros2_bag(entry):
                yield entry
            elif entry.is_dir():
                yield from walk(entry)
            elif entry.suffix.lower() in LOG_SUFFIXES:
                yield entry

    for p in map(Path, paths):
        check_input(p)
        if p.is_dir() and not is_ros2_bag(p):
            found.extend(walk(p))
        else:
            found.append(p)
    unique: dict[Path, Path] = {}
    for p in found:
        unique.setdefault(Path(os.path.realpath(p)), p)
    return list(unique)


def plan_outputs(inputs: Sequence[Path], out_dir: Path) -> list[Task]:
    """One task per input; outputs named after the input, made unique by a hash of its path if needed."""
    names = [output_name(p) for p in inputs]
    counts: dict[str, int] = {}
    for n in names:
        counts[n] = counts.get(n, 0) + 1
    tasks = []
    for p, n in zip(inputs, names, strict=True):
        if counts[n] > 1:
            stem, dot, suffix = n.rpartition(".") if not p.is_dir() else (n, "", "")
            tag = hashlib.sha1(str(p).encode()).hexdigest()[:8]
            n = f"{stem}-{tag}{dot}{suffix}"
        tasks.append(Task(p, out_dir / n))
    return tasks


def stat_signature(path: Path) -> list[int]:
    """[total size, latest mtime_ns] of a file or a directory's files: a cheap "unchanged" test."""
    files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
    stats = [f.stat() for f in files]
    return [sum(st.st_size for st in stats), max((st.st_mtime_ns for st in stats), default=0)]


# --------------------------------------------------------------------------------------- manifest


class Manifest:
    """``OUT_DIR/manifest.jsonl``: append-only, one JSON object per line, fsync'ed per entry."""

    def __init__(self, out_dir: Path) -> None:
        self.path = Path(out_dir) / MANIFEST

    def entries(self) -> list[dict[str, Any]]:
        """Every complete entry that is a JSON object with a string ``input`` (a line cut short by
        a kill, or one that is not an entry, is ignored). The manifest itself is never followed
        through a symlink."""
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_NOFOLLOW)
        except FileNotFoundError:
            return []
        except OSError as exc:
            raise _not_ours(self.path, exc) from exc
        out = []
        with open(fd, encoding="utf-8", errors="replace") as f:
            for line in f:
                if not line.endswith("\n"):
                    continue
                with contextlib.suppress(json.JSONDecodeError, RecursionError):
                    entry = json.loads(line)
                    if isinstance(entry, dict) and isinstance(entry.get("input"), str):
                        out.append(entry)
        return out

    def latest(self) -> dict[str, dict[str, Any]]:
        """The latest entry per input path."""
        return {e["input"]: e for e in self.entries()}

    def append(self, entry: dict[str, Any]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = (json.dumps(entry, sort_keys=True) + "\n").encode()
        try:
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW, 0o644)
        except OSError as exc:
            raise _not_ours(self.path, exc) from exc
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


def clean_temporaries(out_dir: Path) -> list[Path]:
    """Remove the ``.<name>.tmp-*`` files and directories a killed run left in ``out_dir``."""
    removed = []
    for entry in Path(out_dir).glob(".*.tmp-*"):
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
        removed.append(entry)
    return removed


def _not_ours(path: Path, exc: OSError) -> InputError:
    """The error for a manifest or lock that cannot be opened as lanecast's own regular file."""
    if path.is_symlink():
        return InputError(
            path,
            "is a symlink; lanecast does not follow symlinks in its output directory",
            expected="remove it",
        )
    return InputError(path, f"cannot open: {exc.strerror or exc}")


@contextlib.contextmanager
def locked(out_dir: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``out_dir`` (released by the OS if the process dies).

    The lock file is opened without following a symlink and without truncating: a planted
    ``OUT_DIR/.lanecast-annotate.lock`` symlink can neither redirect nor empty another file.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    lock = out_dir / LOCK
    try:
        fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    except OSError as exc:
        raise _not_ours(lock, exc) from exc
    with open(fd, "w") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError as exc:
            raise InputError(
                out_dir, "another `lanecast annotate` run is writing here", expected="one run per OUT_DIR"
            ) from exc
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


# -------------------------------------------------------------------------------------- the task


_QUEUE: Any = None  # progress queue of a local worker process


def _init_worker(q: Any) -> None:
    global _QUEUE
    _QUEUE = q


def annotate_task(task: Task, options: AnnotateOptions, catch_all: bool = True) -> dict[str, Any]:
    """Annotate one log and return its manifest entry (never raises for a bad log).

    With ``catch_all=False`` (Ray) only lanecast's own errors become ``failed`` entries; anything
    else propagates so that Ray retries the task.
    """
    started = time.perf_counter()
    entry: dict[str, Any] = {"input": str(task.input.resolve()), "output": str(task.output), "sha256": None}

    def progress(messages: int, nbytes: int) -> None:
        if _QUEUE is not None:
            _QUEUE.put(messages)

    try:
        entry["stat"] = stat_signature(task.input)
        counts = annotate_log(task.input, task.output, options, progress=progress)
        entry["sha256"] = counts.pop("sha256")  # of the bytes read: the log is read once (the copy)
        entry["output_sha256"] = checksum(task.output)  # what a resumed run trusts (see _own_output)
        entry.update(status="done", counts=counts, error=None)
    except LanecastError as exc:
        entry.update(status="failed", counts=None, error=str(exc))
    except Exception as exc:
        if not catch_all:
            raise
        entry.update(
            status="failed",
            counts=None,
            error=f"{type(exc).__name__}: {exc}",
            traceback=traceback.format_exc(limit=8),
        )
    entry["duration_s"] = round(time.perf_counter() - started, 3)
    entry["finished_at"] = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")
    entry["host"] = os.uname().nodename
    return entry


# ------------------------------------------------------------------------------------------ runner


def relative_to_manifest(output: Path, out_dir: Path) -> str:
    """``output`` as the manifest records it: relative to ``out_dir`` (the manifest's directory) when
    inside it, else absolute; either way it resolves the same from any working directory."""
    output = output.absolute()
    try:
        return output.relative_to(out_dir.absolute()).as_posix()
    except ValueError:
        return str(output)


def plan(inputs: Sequence[Path], out_dir: Path, manifest: Manifest) -> tuple[list[Task], list[Path]]:
    """(tasks to run, inputs skipped as done): done = latest entry done, output exists, same input.

    "Same input": the same size and mtime as recorded (no need to read it again), else the same sha256.
    """
    latest = manifest.latest()
    todo, skipped = [], []
    for task in plan_outputs(inputs, out_dir):
        last = latest.get(str(task.input.resolve()))
        if (
            last is not None
            and last.get("status") == "done"
            and _own_output(last, task, out_dir)
            and (last.get("stat") == stat_signature(task.input) or last.get("sha256") == checksum(task.input))
        ):
            skipped.append(task.input)
        else:
            todo.append(task)
    return todo, skipped


def _own_output(entry: dict[str, Any], task: Task, out_dir: Path) -> bool:
    """An entry's output is trusted only as this task's own output inside ``out_dir`` (no symlink on
    the way) whose checksum is the one recorded when it was written: a forged or stale line that
    points elsewhere, or at a file changed since, does not make a log "done"."""
    recorded = entry.get("output")
    if not isinstance(recorded, str) or not isinstance(entry.get("output_sha256"), str):
        return False
    output = out_dir / recorded
    if os.path.normpath(output.absolute()) != os.path.normpath(task.output.absolute()):
        return False
    if output.is_symlink() or not output.exists():
        return False
    if os.path.realpath(output) != os.path.join(os.path.realpath(out_dir), output.name):
        return False
    return bool(checksum(output) == entry["output_sha256"])


def run_bulk(
    paths: Sequence[Path],
    out_dir: Path,
    options: AnnotateOptions | None = None,
    *,
    workers: int = 1,
    engine: str = "local",
    address: str | None = None,
    retries: int = 2,
) -> BulkResult:
    """Annotate every log named by ``paths`` into ``out_dir``; resume from its manifest.

    ``out_dir`` is made absolute here, so that workers (other processes, Ray nodes with another
    working directory) write where the caller asked.
    """
    out_dir = Path(out_dir).absolute()
    options = options or AnnotateOptions()
    if workers < 1:
        raise InputError(None, f"--workers must be at least 1, got {workers}")
    inputs = [p.absolute() for p in discover(paths, exclude=out_dir)]
    if not inputs:
        raise InputError(
            None, f"no logs found in {', '.join(map(str, paths))}", expected="*.mcap, *.bag or ROS 2 bags"
        )
    result = BulkResult(out_dir=out_dir)
    with locked(out_dir):
        clean_temporaries(out_dir)
        manifest = Manifest(out_dir)
        tasks, result.skipped = plan(inputs, out_dir, manifest)
        progress = bar(desc="annotate", total=len(inputs), unit="log")
        progress.update(len(result.skipped))
        messages = 0

        def on_messages(n: int) -> None:
            nonlocal messages
            messages += n
            progress.set_postfix_str(f"{messages:,} msgs")

        def on_entry(entry: dict[str, Any]) -> None:
            entry["output"] = relative_to_manifest(Path(entry["output"]), out_dir)
            manifest.append(entry)
            result.entries.append(entry)
            progress.update(1)
            if entry["status"] == "failed":
                progress.write(f"lanecast annotate: FAILED {entry['input']}: {entry['error']}")

        try:
            if not tasks:
                pass
            elif engine == "ray":
                _run_ray(
                    tasks, options, on_entry, on_messages, address=address, workers=workers, retries=retries
                )
            elif workers == 1:
                _run_inline(tasks, options, on_entry, on_messages)
            else:
                _run_pool(tasks, options, on_entry, on_messages, workers=workers)
        finally:
            progress.close()
    return result


class _Direct:
    """A stand-in for the workers' progress queue that reports at once."""

    def __init__(self, report: Callable[[int], None]) -> None:
        self.put = report


def _run_inline(
    tasks: Sequence[Task],
    options: AnnotateOptions,
    on_entry: Callable[[dict[str, Any]], None],
    on_messages: Callable[[int], None],
) -> None:
    global _QUEUE
    _QUEUE = _Direct(on_messages)  # in-process: the bar moves while a log is copied
    try:
        for task in tasks:
            on_entry(annotate_task(task, options))
    finally:
        _QUEUE = None


def _run_pool(
    tasks: Sequence[Task],
    options: AnnotateOptions,
    on_entry: Callable[[dict[str, Any]], None],
    on_messages: Callable[[int], None],
    *,
    workers: int,
) -> None:
    """At most ``workers`` logs in flight; a worker that dies fails its logs and the pool is renewed."""
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    pending = list(tasks)[::-1]

    def drain() -> None:
        with contextlib.suppress(queue_mod.Empty):
            while True:
                on_messages(q.get_nowait())

    while pending:
        with ProcessPoolExecutor(
            max_workers=workers, mp_context=ctx, initializer=_init_worker, initargs=(q,)
        ) as pool:
            running: dict[Future[dict[str, Any]], Task] = {}
            broken = False
            while (pending or running) and not broken:
                while pending and len(running) < workers:
                    task = pending.pop()
                    running[pool.submit(annotate_task, task, options)] = task
                done, _ = wait(list(running), timeout=0.25, return_when=FIRST_COMPLETED)
                drain()
                for fut in done:
                    task = running.pop(fut)
                    try:
                        on_entry(fut.result())
                    except BrokenProcessPool:
                        broken = True
                        on_entry(_crashed(task))
            for task in running.values():  # the pool broke: the others in flight died with it
                on_entry(_crashed(task))
        drain()


def _crashed(
    task: Task, reason: str = "the worker process died (out of memory or killed?)"
) -> dict[str, Any]:
    return {
        "input": str(task.input.resolve()),
        "output": str(task.output),
        "sha256": None,
        "status": "failed",
        "counts": None,
        "error": reason,
        "duration_s": None,
        "finished_at": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
    }


def _run_ray(
    tasks: Sequence[Task],
    options: AnnotateOptions,
    on_entry: Callable[[dict[str, Any]], None],
    on_messages: Callable[[int], None],
    *,
    address: str | None,
    workers: int,
    retries: int,
) -> None:
    """The same task on Ray: retried ``retries`` times when its worker dies or it raises unexpectedly."""
    try:
        import ray
    except ImportError as exc:
        raise InputError(None, "--engine ray needs Ray", expected="pip install 'lanecast[ray]'") from exc
    started_here = not ray.is_initialized()
    if started_here:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(num_cpus=max(workers, 2), include_dashboard=False, log_to_driver=False)
    try:
        remote = ray.remote(max_retries=retries, retry_exceptions=True)(annotate_task)
        refs = {remote.remote(task, options, False): task for task in tasks}
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1, timeout=1.0)
            for ref in done:
                task = refs.pop(ref)
                try:
                    entry = ray.get(ref)
                except Exception as exc:  # retries exhausted: the log fails, the run goes on
                    entry = _crashed(
                        task, f"Ray task failed after {retries} retries: {type(exc).__name__}: {exc}"
                    )
                on_messages(int((entry.get("counts") or {}).get("messages", 0)))
                on_entry(entry)
    finally:
        if started_here:
            ray.shutdown()
