"""`lanecast windows`: a track table (or any readable input) -> a windows dataset directory."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.progress import activity
from lanecast.workflows.arguments import MAX_SEED, integer, number
from lanecast.workflows.bulk import backends
from lanecast.workflows.vocabulary import HelpFormatter, add_force_option, add_location_option


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "windows",
        help="cut a track table into network windows (4x8x30 inputs, 5 s futures, maneuver labels, splits)",
        description=(
            "Resample TABLE to 10 Hz, find every vehicle's seven neighbours, cut windows (3 s history, "
            "5 s future, every --stride frames), label maneuvers, split by track, and write the dataset "
            "directory training memory-maps: inputs.npy, present.npy, future.npy, maneuver.npy, "
            "windows.parquet, manifest.json. Windows never span a gap in a track. Streams: one recording "
            "(or a group of small ones, or a group of whole tracks of a long one with the traffic "
            "around them) at a time is read, cut and appended to the dataset on disk, so memory "
            "stays bounded whatever the dataset or recording length; the directory appears only "
            "when complete. --workers/--engine ray spread recordings over processes or a cluster with "
            "the same result as one process."
        ),
        epilog=(
            "examples:\n"
            "  lanecast windows sim.parquet --out windows/sim\n"
            "  lanecast windows sim-queue/ --out windows/queue --split hash --seed 3 --stride 5   # any input convert reads\n"
            "  lanecast windows lanecast-demo/highd/ --out windows/demo --workers 2"
        ),
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "table", nargs="+", metavar="TABLE", help="track table(s) (Parquet) or any input `convert` reads"
    )
    p.add_argument("--out", required=True, type=Path, help="output directory (written atomically)")
    p.add_argument("--format", choices=sorted(registry.READERS), help="input format (default: detected)")
    add_location_option(p)
    p.add_argument(
        "--split",
        choices=("pip", "hash", "none"),
        default="pip",
        help="split by track into train/val/test, 70/10/20: pip = the PiP convention (Song et al., ECCV 2020; "
        "by vehicle id within each recording: the lowest 70 %% of the id range train, the next 10 %% val, "
        "the rest test), hash = a seeded hash of (recording, track), none = every track in split 'none' "
        "(default: pip)",
    )
    p.add_argument("--seed", type=integer(0, MAX_SEED), default=0, help="seed of the hash split (default: 0)")
    p.add_argument(
        "--stride", type=integer(1, 36_000), default=10, help="frames at 10 Hz between windows (default: 10)"
    )
    p.add_argument(
        "--neighbours",
        choices=("auto", "source", "lanes", "bands"),
        default="auto",
        help="neighbour selection (default: the source's ids, else lanes, else lateral bands)",
    )
    p.add_argument(
        "--neighbour-range",
        type=number(0, 10_000, "m", above=True),
        default=100.0,
        metavar="M",
        help="a vehicle farther ahead or behind is no neighbour, in metres (default: 100)",
    )
    p.add_argument(
        "--no-future",
        action="store_true",
        help="also cut windows without 5 s of future (future NaN, maneuver -1 where unknown)",
    )
    backends.add_arguments(p, "recordings processed")
    add_force_option(
        p,
        help="replace OUT_DIR even if it holds files that are not a windows dataset's (they are deleted; "
        "by default such a directory is named and refused, and an earlier dataset is replaced)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lanecast.io_adapters.contracts.windows import DATASET_FILES
    from lanecast.io_adapters.files import ANY_FILES, check_output_dir
    from lanecast.io_adapters.formats import streaming
    from lanecast.pipeline.write_windows import WindowOptions, write_windows
    from lanecast.workflows.bulk import freed_memory

    started = time.perf_counter()
    # before the work: a file there, or a directory holding a user's files, was refused at the end
    check_output_dir(args.out, replaces=ANY_FILES if args.force else DATASET_FILES)
    backends.check(args.workers, args.engine)
    freed_memory.keep_freed_memory(arrow=True)  # pieces reuse what the previous one freed
    with streaming.spill_directory(args.out) as spill:  # NGSIM exports: a spill per recording
        options = {"location": args.location} if args.location else {}
        pieces = streaming.plan(
            args.table, fmt=args.format, spill_dir=spill.path, options=options, long="context"
        )
        ordered_map = backends.mapper_from_args(args, args.table, args.out)
        count = f"{len(pieces):,} piece" + ("s" if len(pieces) != 1 else "")
        with activity(f"windows: resampling, neighbours and tensors of {count}"):
            windows = write_windows(
                pieces,
                args.out,
                WindowOptions(
                    stride=args.stride,
                    require_future=not args.no_future,
                    split=args.split,
                    seed=args.seed,
                    neighbours=args.neighbours,
                    neighbour_range=args.neighbour_range,
                ),
                ordered_map=ordered_map,
                sources={"inputs": [str(Path(p)) for p in args.table]},
                replace_any=args.force,
            )
    m = windows.manifest
    counts = ", ".join(f"{k} {v:,}" for k, v in m["counts"].items() if v)
    labels = ", ".join(f"{k} {v:,}" for k, v in m["label_distribution"].items())
    pieces_read = f"{len(pieces):,} piece" + ("s" if len(pieces) != 1 else "")
    print(
        f"wrote {args.out}: {len(windows):,} windows ({counts}) from {pieces_read} "
        f"in {time.perf_counter() - started:.1f} s"
    )
    skew = split_skew(m["counts"], args.split)
    if skew:
        print(f"  note: {skew}")
    print(f"  maneuver labels (all steps): {labels}")
    methods = sorted(
        {r["neighbour_method"] for r in m["sources"]["recordings"].values() if r["neighbour_method"]}
    )
    print(f"  neighbours from: {', '.join(methods)}")
    for name, why in m["skipped_recordings"].items():
        print(f"  skipped {name}: {why}")
    return 0


def split_skew(counts: dict[str, int], method: str) -> str | None:
    """A word when a 70/10/20 split came out far from it (the pip split follows vehicle ids, so one
    outlier id, e.g. 9999 among ids up to 300, moves nearly every track into train)."""
    total = sum(counts.get(s, 0) for s in ("train", "val", "test"))
    if method == "none" or total < 50:
        return None
    shares = [counts.get(s, 0) / total for s in ("train", "val", "test")]
    if all(abs(share - target) <= 0.1 for share, target in zip(shares, (0.7, 0.1, 0.2), strict=True)):
        return None
    percent = " / ".join(f"{100 * share:.0f}" for share in shares)
    advice = (
        " (pip follows vehicle ids: an outlier id stretches the range; --split hash does not)"
        if method == "pip"
        else ""
    )
    return f"the {method} split came out {percent} % train / val / test, not 70 / 10 / 20{advice}"
