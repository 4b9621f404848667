"""Fair comparisons on a shared machine: variants timed in turn (A B C, C B A, A B C …), medians reported.

Every benchmark script compares variants with these helpers so that load from other work hits all
of them alike: one round times each variant once, the order reverses every round, and a summary
gives the median with its min–max over the rounds (the best-of only beside it). Each script prints
:func:`machine_line` before and after, with the load average.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass


def machine_line(when: str = "") -> str:
    """CPUs and the 1/5/15-minute load averages, e.g. for the header of a benchmark's output."""
    one, five, fifteen = os.getloadavg()
    label = f" ({when})" if when else ""
    return f"load average{label}: {one:.2f} {five:.2f} {fifteen:.2f} on {os.cpu_count()} CPUs"


@dataclass(frozen=True)
class Samples:
    """One variant's measurements, one per round."""

    values: list[float]

    @property
    def median(self) -> float:
        return statistics.median(self.values)

    @property
    def low(self) -> float:
        return min(self.values)

    @property
    def high(self) -> float:
        return max(self.values)

    def text(self, fmt: str = ",.0f", higher_is_better: bool = True) -> str:
        """``median (min–max; best b)``."""
        best = self.high if higher_is_better else self.low
        return f"{self.median:{fmt}} ({self.low:{fmt}}–{self.high:{fmt}}; best {best:{fmt}})"


def round_orders(names: list[str], rounds: int) -> list[list[str]]:
    """The order of the variants in each round: forward, backward, forward, …"""
    return [names if r % 2 == 0 else names[::-1] for r in range(rounds)]


def interleaved_times(
    fns: dict[str, Callable[[], object]], rounds: int, warmup: int = 1
) -> dict[str, Samples]:
    """Wall seconds of one call of each function, ``rounds`` rounds taken in turn (after ``warmup``)."""
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for order in round_orders(list(fns), rounds):
        for name in order:
            start = time.perf_counter()
            fns[name]()
            times[name].append(time.perf_counter() - start)
    return {name: Samples(values) for name, values in times.items()}


def interleaved_rates(
    fns: dict[str, Callable[[], object]], units_per_call: float, burst_s: float, rounds: int
) -> dict[str, Samples]:
    """Units per second of each function: every round runs each for one burst of ``burst_s`` seconds."""
    for fn in fns.values():
        for _ in range(2):
            fn()
    rates: dict[str, list[float]] = {name: [] for name in fns}
    for order in round_orders(list(fns), rounds):
        for name in order:
            n, start = 0, time.perf_counter()
            while (elapsed := time.perf_counter() - start) < burst_s:
                fns[name]()
                n += 1
            rates[name].append(n * units_per_call / elapsed)
    return {name: Samples(values) for name, values in rates.items()}


def ratio(a: Samples, b: Samples) -> str:
    """Median of a over median of b, with the range of the per-round ratios (rounds paired in time)."""
    per_round = [x / y for x, y in zip(a.values, b.values, strict=True)]
    return f"{a.median / b.median:.2f}× (per round {min(per_round):.2f}–{max(per_round):.2f})"
