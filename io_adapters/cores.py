"""How many threads this process may use: the machine's free cores, shared among a bulk run's workers.

The cores this process may run on, less those the machine's other work keeps busy (:func:`busy`),
shared among the worker processes of a bulk run (``--workers N`` sets
``LANECAST_WORKERS`` in each), at least one; ``LANECAST_THREADS`` overrides. Used by ONNX Runtime's
sessions and torch's, the MCAP reader's SceneUpdate decoding and column-wise work on large tables
(:func:`map_columns`). Under load or beside other workers the answer is one thread, as more threads
then only contend (BENCHMARKS.md).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar

_T = TypeVar("_T")
_R = TypeVar("_R")

#: Environment variable overriding the threads of this process.
THREADS_ENV = "LANECAST_THREADS"
#: Environment variable a bulk run's worker processes carry: how many share the machine.
WORKERS_ENV = "LANECAST_WORKERS"


def choose_threads(cores: int, load: float, workers: int = 1) -> int:
    """Threads for each of ``workers`` processes on ``cores`` cores of which the machine's other
    work keeps ``load`` busy (:func:`busy`): the free cores shared out, at least 1."""
    free = min(cores, cores - round(load))
    return max(1, free // max(1, workers))


def default_threads() -> int:
    """Threads for this process: ``$LANECAST_THREADS``, else :func:`choose_threads` of the cores it
    may run on, the load average and ``$LANECAST_WORKERS``."""
    value = os.environ.get(THREADS_ENV, "")
    if value.strip().isdigit():
        return max(1, int(value))
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    workers = os.environ.get(WORKERS_ENV, "1")
    return choose_threads(cores, busy(), int(workers) if workers.isdigit() else 1)


def busy(loadavg: str | None = None) -> float:
    """Cores the machine's other work keeps busy: the 1-minute load average, or the threads running
    right now besides this one where fewer (``/proc/loadavg``, text ``loadavg`` for tests).

    The average alone lags: a minute after lanecast's own previous command (or a benchmark's
    previous round) it still counts that work, and an idle machine would get one thread.
    """
    try:
        text = loadavg if loadavg is not None else Path("/proc/loadavg").read_text()
        fields = text.split()
        return min(float(fields[0]), max(0, int(fields[3].split("/")[0]) - 1))
    except (OSError, IndexError, ValueError):
        return os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0


def map_columns(task: Callable[[_T], _R], columns: Iterable[_T], threads: int | None = None) -> list[_R]:
    """``[task(c) for c in columns]`` on ``threads`` threads (default :func:`default_threads`), for
    work on whole columns that releases the GIL (Arrow's take and copies, numpy's ufuncs)."""
    items = list(columns)
    threads = min(default_threads() if threads is None else threads, len(items))
    if threads < 2:
        return [task(c) for c in items]
    from concurrent.futures import ThreadPoolExecutor  # only where threads help: not on every start

    with ThreadPoolExecutor(threads) as pool:
        return list(pool.map(task, items))
