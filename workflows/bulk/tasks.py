"""Running the per-log annotation task of a bulk run: in-process, in worker processes or on Ray.

:func:`annotate_task` annotates one log and returns its manifest entry (a bad log becomes a
``failed`` entry, never an exception). :func:`run_inline` runs tasks in this process (the progress
bar moves while a log is copied); :func:`run_pool` in a ``ProcessPoolExecutor`` (spawned workers
report copied messages through a queue; a worker that dies fails its logs and the pool is renewed);
:func:`run_ray` submits the same task to a Ray cluster (``num_cpus=1``, retried when its worker
dies or it raises unexpectedly; see ``lanecast.workflows.bulk.ray_backend``).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import multiprocessing as mp
import os
import queue as queue_mod
import time
import traceback
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from lanecast.io_adapters.errors import LanecastError
from lanecast.io_adapters.files import checksum
from lanecast.workflows.annotation.annotate_log import (
    AnnotateOptions,
    annotate_log,
)
from lanecast.workflows.bulk import ray_backend
from lanecast.workflows.bulk.discovery import Task
from lanecast.workflows.bulk.manifest import stat_signature

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
        entry["output_sha256"] = checksum(task.output)  # what a resumed run trusts (see own_output)
        entry.update(status="done", counts=counts, error=None)
    except LanecastError as exc:
        entry.update(status="failed", counts=None, error=str(exc))
    except OSError as exc:  # the environment, not a bug: a full disk or a file-size limit names the output
        reason = os.strerror(exc.errno) if exc.errno else str(exc)
        entry.update(status="failed", counts=None, error=f"{exc.filename or task.output}: {reason}")
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


class _Direct:
    """A stand-in for the workers' progress queue that reports at once."""

    def __init__(self, report: Callable[[int], None]) -> None:
        self.put = report


def run_inline(
    tasks: Sequence[Task],
    options: AnnotateOptions,
    on_entry: Callable[[Task, dict[str, Any]], None],
    on_messages: Callable[[int], None],
) -> None:
    global _QUEUE
    _QUEUE = _Direct(on_messages)  # in-process: the bar moves while a log is copied
    try:
        for task in tasks:
            on_entry(task, annotate_task(task, options))
    finally:
        _QUEUE = None


def run_pool(
    tasks: Sequence[Task],
    options: AnnotateOptions,
    on_entry: Callable[[Task, dict[str, Any]], None],
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
                        on_entry(task, fut.result())
                    except BrokenProcessPool:
                        broken = True
                        on_entry(task, crashed_entry(task))
            for task in running.values():  # the pool broke: the others in flight died with it
                on_entry(task, crashed_entry(task))
        drain()


def crashed_entry(
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


def run_ray(
    tasks: Sequence[Task],
    options: AnnotateOptions,
    on_entry: Callable[[Task, dict[str, Any]], None],
    on_messages: Callable[[int], None],
    *,
    out_dir: Path,
    retries: int,
) -> None:
    """The same task on Ray, one CPU each: retried ``retries`` times when its worker dies or it
    raises unexpectedly. The workers must see the inputs and OUT_DIR by the same absolute paths."""
    ray = ray_backend.ray_module()  # connected by run_bulk
    ray_backend.refuse_unreachable_paths([out_dir, *(t.input for t in tasks)])
    remote = ray.remote(num_cpus=1, max_retries=retries, retry_exceptions=True)(annotate_task)
    refs = {remote.remote(task, options, False): task for task in tasks}
    while refs:
        done, _ = ray.wait(list(refs), num_returns=1, timeout=1.0)
        for ref in done:
            task = refs.pop(ref)
            try:
                entry = ray.get(ref)
            except Exception as exc:  # retries exhausted: the log fails, the run goes on
                entry = crashed_entry(
                    task, f"Ray task failed after {retries} retries: {type(exc).__name__}: {exc}"
                )
            on_messages(int((entry.get("counts") or {}).get("messages", 0)))
            on_entry(task, entry)
