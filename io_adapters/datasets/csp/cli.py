"""``lanecast convert … --to csp``: the command-line side of :func:`write_csp`."""

from __future__ import annotations

import argparse
import os
from typing import TYPE_CHECKING

from lanecast.io_adapters.errors import InputError, UsageError
from lanecast.io_adapters.formats import registry

if TYPE_CHECKING:  # read by convert's parser: the writer only when --to csp runs
    from lanecast.io_adapters.datasets.csp.inputs import Resample

FORMATS = ("ngsim", "highd")
HELP = (
    "csp: conv-social-pooling's TrainSet.mat, ValSet.mat, TestSet.mat (traj, tracks) in the directory "
    "--out, as its preprocess_data.m writes them from raw NGSIM files (datasets: US-101 then I-80, "
    "by name); from highD by PiP's convention (recording r: 2r-1 its lower lanes, 2r its upper ones)"
)


def input_format(inputs: list[str], fmt: str | None) -> str:
    """``ngsim`` or ``highd``: the one format of every input (``--format`` or detected)."""
    from lanecast.io_adapters.files import check_input

    found = {fmt or registry.detect(check_input(p)) for p in inputs}
    if len(found) != 1 or not found <= set(FORMATS):
        raise UsageError(
            "--to csp",
            f"inputs of format {', '.join(sorted(found))}",
            expected="raw NGSIM files or highD recordings, one kind at a time",
        )
    return found.pop()


def run_csp(args: argparse.Namespace, resample: Resample | None = None) -> int:
    """Check the output directory, then write the sets; prints the dataset ids it gave."""
    from lanecast.io_adapters.datasets.csp.writer import check_csp_output, write_csp

    check_csp_output(args.out)
    fmt = input_format(list(args.inputs), args.format)
    if os.path.realpath(args.out) in {os.path.realpath(p) for p in args.inputs}:
        raise InputError(args.out, "the output would overwrite an input", expected="a new output directory")
    if getattr(args, "engine", "local") != "local":
        raise UsageError(
            "--engine", f"{args.engine}: --to csp reads on local processes", expected="--workers N"
        )
    record = write_csp(
        args.inputs, args.out, fmt=fmt, location=args.location, workers=args.workers, resample=resample
    )
    for ds in record["datasets"]:
        print(f"dataset {ds['id']}: {ds['file']} ({ds['source']}, {ds['rows']:,} rows)")
    counts = ", ".join(f"{name} {info['rows']:,} rows" for name, info in record["sets"].items())
    print(f"wrote {args.out} (csp): {counts} in {record['seconds']:.1f} s")
    return 0
