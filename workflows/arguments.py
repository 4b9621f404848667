"""Argument types for numeric command-line options: a value outside its range is a usage error.

argparse's plain ``type=int`` takes any integer, and a huge one reached numpy or the OS as a
traceback (``--stride 99999999999999999999``: "Python int too large to convert to C long") or was
silently taken (``--examples -1``). These types check the range where the option is parsed, so the
message is argparse's usual one line, exit 2, naming the option, the value and the range.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

#: the largest seed every consumer takes (numpy's generators, SUMO's --seed, the hash split)
MAX_SEED = 2**31 - 1
#: the maneuver sequences there are to draw: 3 classes at each of 5 horizons
MANEUVER_SEQUENCES = 3**5
#: parallel workers (processes here, tasks on a Ray cluster)
MAX_WORKERS = 1024
#: example scenes drawn into a report
MAX_EXAMPLES = 100
#: a time in seconds whose nanoseconds fit int64, the track table's time unit (about 292 years)
MAX_TIME_S = 9.2e9


def integer(lowest: int, highest: int) -> Callable[[str], int]:
    """An argparse type: an integer from ``lowest`` to ``highest``."""
    expected = f"an integer from {lowest} to {highest}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not lowest <= value <= highest:
            raise argparse.ArgumentTypeError(f"{text or repr(text)} (expected {expected})")
        return value

    return parse


def number(lowest: float, highest: float, unit: str = "", *, above: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number from ``lowest`` (or above it, when ``above``) to ``highest``."""
    unit = f" {unit}" if unit else ""
    if above:
        expected = f"a number above {lowest:g}, at most {highest:g}{unit}"
    else:
        expected = f"a number from {lowest:g} to {highest:g}{unit}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        in_range = (value > lowest if above else value >= lowest) and value <= highest
        if not (math.isfinite(value) and in_range):
            raise argparse.ArgumentTypeError(f"{text or repr(text)} (expected {expected})")
        return value

    return parse
