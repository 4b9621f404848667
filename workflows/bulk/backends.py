"""Where per-input tasks run: in this process, on local worker processes, or on a Ray cluster.

Shared by the commands that spread work over inputs (`annotate` through bulk.py, `convert` and
`windows`): one way to connect to Ray (ray_backend, through :func:`ray_session`), one ordered map over tasks
(:func:`ordered_map`) and one set of command-line options (:func:`add_arguments`). On a cluster,
inputs and outputs must be on storage every node sees; tasks write there and return small results.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from lanecast.io_adapters import cores
from lanecast.io_adapters.errors import InputError, LanecastError
from lanecast.workflows.arguments import MAX_WORKERS, integer
from lanecast.workflows.bulk import ray_backend

if TYPE_CHECKING:
    from concurrent.futures import Future

T = TypeVar("T")
R = TypeVar("R")
BACKENDS = ("local", "ray")


def add_arguments(p: argparse.ArgumentParser, done: str) -> None:
    """``--workers``, ``--engine`` (the backend), ``--address`` and ``--retries`` of a command that
    spreads its inputs; ``done`` says what ``--workers`` counts (``"logs annotated"``)."""
    p.add_argument("--workers", type=integer(1, MAX_WORKERS), default=1, help=f"{done} in parallel")
    p.add_argument("--engine", choices=BACKENDS, default="local", help="local processes or a Ray cluster")
    p.add_argument(
        "--address",
        help="Ray: host:port of a cluster's head, or ray://host:10001 (default: RAY_ADDRESS, else the "
        "cluster `ray start` runs on this machine, else a new local Ray)",
    )
    p.add_argument(
        "--retries", type=integer(0, 100), default=2, help="Ray: retries of a task whose worker died"
    )


def check(workers: int, engine: str) -> None:
    if workers < 1:
        raise InputError(None, f"--workers {workers}", expected="at least 1")
    if engine not in BACKENDS:
        raise InputError(None, f"--engine {engine}", expected=f"one of {BACKENDS}")


@contextlib.contextmanager
def ray_session(address: str | None, workers: int) -> Iterator[Any]:
    """The ``ray`` module connected as bulk runs connect (:mod:`lanecast.workflows.bulk.ray_backend`:
    fail fast on a wrong address, join a running cluster, else a local Ray with ``workers`` CPUs);
    a Ray started here is shut down on exit."""
    started_here = ray_backend.connect(address, workers)
    ray = ray_backend.ray_module()
    try:
        yield ray
    finally:
        if started_here:
            ray.shutdown()


def ordered_map(
    fn: Callable[[T], R],
    items: Sequence[T],
    *,
    workers: int = 1,
    engine: str = "local",
    address: str | None = None,
    retries: int = 2,
    paths: Sequence[Path] = (),
) -> Iterator[R]:
    """``fn(item)`` for every item, yielded in item order: inline (1 local worker), on ``workers``
    spawned processes, or as Ray tasks. At most ``2 * workers`` tasks are in flight, so that what
    finished tasks leave on disk stays bounded. ``fn`` must be picklable (a module-level function
    or a ``functools.partial`` of one). A task's LanecastError is raised here as it is. On Ray,
    ``paths`` (inputs, the output's directory) must be visible to the workers by the same names."""
    check(workers, engine)
    if engine == "ray":
        yield from _ray_map(fn, items, workers=workers, address=address, retries=retries, paths=paths)
    elif workers == 1:
        for item in items:
            yield fn(item)
    else:
        import multiprocessing as mp  # only for workers: 0.01–0.02 s of every command's start-up
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(
            max_workers=workers,
            mp_context=mp.get_context("spawn"),
            initializer=_start_worker,
            initargs=(workers,),
        ) as pool:
            pending: deque[Future[R]] = deque()
            for item in items:
                pending.append(pool.submit(fn, item))
                if len(pending) >= 2 * workers:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()


def mapper_from_args(
    args: argparse.Namespace, inputs: Sequence[Path | str], out: Path
) -> Callable[..., Iterator[Any]] | None:
    """``ordered_map`` bound to a command's ``--workers/--engine/--address/--retries`` (the paths
    the workers must see: ``inputs`` and ``out``'s folder), or None for one local process."""
    if args.workers <= 1 and args.engine != "ray":
        return None
    return functools.partial(
        ordered_map,
        workers=args.workers,
        engine=args.engine,
        address=args.address,
        retries=args.retries,
        paths=[*(Path(p).resolve() for p in inputs), out.resolve().parent],
    )


def _start_worker(workers: int) -> None:
    """A local worker process: ``workers`` share the machine (each model's threads: their share of
    the free cores, lanecast.io_adapters.cores.default_threads); freed memory kept for reuse."""
    from lanecast.workflows.bulk import freed_memory  # pyarrow: only where work runs

    os.environ[cores.WORKERS_ENV] = str(workers)
    freed_memory.keep_freed_memory()


def _call(fn: Callable[[T], R], item: T) -> R:
    from lanecast.workflows.bulk import freed_memory

    os.environ.setdefault(cores.THREADS_ENV, "1")  # a Ray task holds one CPU
    freed_memory.keep_freed_memory()  # once per Ray worker process
    return fn(item)


def _ray_map(
    fn: Callable[[T], R],
    items: Sequence[T],
    *,
    workers: int,
    address: str | None,
    retries: int,
    paths: Sequence[Path],
) -> Iterator[R]:
    with ray_session(address, workers) as ray:
        if paths:
            ray_backend.refuse_unreachable_paths(list(paths))
        # one CPU each; retried only when a worker dies: a task's own error is deterministic
        remote = ray.remote(num_cpus=1, max_retries=retries, retry_exceptions=False)(_call)
        fn_ref = ray.put(fn)
        pending: deque[Any] = deque()

        def result(ref: Any) -> R:
            try:
                value: R = ray.get(ref)
            except ray.exceptions.RayTaskError as exc:
                if isinstance(exc.cause, LanecastError):
                    raise exc.cause from None
                raise
            return value

        for item in items:
            pending.append(remote.remote(fn_ref, item))
            if len(pending) >= 2 * max(workers, 1):
                yield result(pending.popleft())
        while pending:
            yield result(pending.popleft())
