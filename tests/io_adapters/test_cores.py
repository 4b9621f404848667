"""The threads a process may use (lanecast.io_adapters.cores)."""

from __future__ import annotations

import os

import pytest

from lanecast.io_adapters.cores import THREADS_ENV, WORKERS_ENV, busy, choose_threads, default_threads


def test_threads_are_the_free_cores_shared_among_workers(monkeypatch: pytest.MonkeyPatch) -> None:
    assert choose_threads(cores=2, load=0.3) == 2  # an idle machine: every core
    assert choose_threads(cores=2, load=1.2) == 1  # one core busy elsewhere
    assert choose_threads(cores=2, load=9.0) == 1  # loaded: never below one
    assert choose_threads(cores=8, load=0.0, workers=4) == 2  # four workers share eight cores
    assert choose_threads(cores=8, load=2.0, workers=4) == 1
    assert choose_threads(cores=8, load=0.0, workers=16) == 1
    monkeypatch.setenv(THREADS_ENV, "3")
    assert default_threads() == 3  # the user's word first
    monkeypatch.delenv(THREADS_ENV)
    monkeypatch.setenv(WORKERS_ENV, "64")
    assert default_threads() == 1
    monkeypatch.delenv(WORKERS_ENV)
    assert 1 <= default_threads() <= (os.cpu_count() or 1)


def test_busy_cores_are_the_load_or_the_threads_running_now_whichever_is_fewer() -> None:
    assert busy("1.20 0.90 0.60 1/350 4242") == 0  # only this process runs: the average still counts its past
    assert busy("0.10 0.05 0.01 3/350 4242") == pytest.approx(0.1)  # a moment's others: the average
    assert busy("3.90 3.80 3.70 5/350 4242") == 3.9  # a loaded machine
    assert busy("2.00 2.00 2.00 2/350 4242") == 1  # one other runs now
    assert 0 <= busy() <= 1e6  # this machine's own, whatever it reads


def test_map_columns_keeps_the_order_of_its_items_on_one_thread_or_many() -> None:
    import threading

    from lanecast.io_adapters.cores import map_columns

    seen: set[int] = set()

    def square(x: int) -> int:
        seen.add(threading.get_ident())
        return x * x

    items = list(range(40))
    assert map_columns(square, items, threads=1) == [x * x for x in items]
    assert seen == {threading.get_ident()}  # one thread: the caller's own
    assert map_columns(square, items, threads=4) == [x * x for x in items]
    assert map_columns(square, [], threads=4) == []
