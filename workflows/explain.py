"""`lanecast explain`: what-if forecasts of one target with its neighbours removed (the paper's Figs. 4–5).

INPUT is a windows dataset, a track table or anything ``convert`` reads (a highD directory, NGSIM
file, MCAP log, ROS bag): the window of ``--track`` at ``--time`` is cut (or looked up), forecast as it
is and with each chosen neighbour removed, and drawn into ``--out`` (``explain.html``,
``explain.json``, one PNG per scene). See ``lanecast.models.explain``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.progress import activity
from lanecast.models.card import provenance, provenance_line
from lanecast.workflows.arguments import MANEUVER_SEQUENCES, MAX_TIME_S, integer, number
from lanecast.workflows.vocabulary import HelpFormatter, add_force_option, add_model_option

if TYPE_CHECKING:  # the parser (--help) imports none of the work's modules
    import numpy as np
    import pyarrow as pa

    from lanecast.io_adapters.contracts.windows import Windows

STEP_NS = 100_000_000  # windows sit on the 10 Hz grid


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "explain",
        help="what-if forecasts of one target with its neighbours removed (the paper's Figs. 4-5)",
        description=(
            "Forecast one target at one time with its real neighbourhood and with each chosen neighbour removed "
            "(its slot of the input zeroed, as the paper does), and show how the maneuver probabilities and the "
            "trajectory change: explain.html (the scenes drawn as in the paper, a table ranked by influence), "
            "explain.json and PNGs in --out. INPUT: a windows dataset, a track table, or any input convert "
            "reads (highD directory, NGSIM file, MCAP log, ROS bag). Neighbour slots: FL F FR L R RL RR."
        ),
        epilog=(
            "examples:\n"
            "  lanecast explain windows/sim --track 75 --time 58.3 --out explain/\n"
            "  lanecast explain logs/sim.mcap --track 22 --time 7 --remove F,RL --out explain/   # a log: --time on its clock\n"
            "  lanecast explain sim/ --track 75 --time 58.3 --remove F+FL --out explain/"
        ),
        formatter_class=HelpFormatter,
    )
    p.add_argument("input", type=Path, metavar="INPUT", help="windows dataset, track table, dataset or log")
    p.add_argument("--track", type=int, required=True, metavar="ID", help="the target's track id")
    p.add_argument(
        "--time",
        type=number(-MAX_TIME_S, MAX_TIME_S, "s"),
        required=True,
        metavar="T",
        help="forecast time t0 in seconds (the track's time base; in a windows dataset cut with a stride, the nearest window)",
    )
    p.add_argument(
        "--recording", metavar="NAME", help="the recording, when INPUT holds several with this track id"
    )
    p.add_argument(
        "--remove",
        metavar="A,B+C",
        help="what-ifs, comma-separated; '+' removes neighbours together (e.g. F,RL,FL+F). Without it: --all",
    )
    p.add_argument(
        "--all",
        action="store_true",
        help="each neighbour present in the window removed in turn (also with --remove)",
    )
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    add_model_option(p)
    p.add_argument(
        "--top-k", type=integer(1, MANEUVER_SEQUENCES), default=3, help="maneuver sequences drawn per scene"
    )
    add_force_option(p)
    p.set_defaults(func=run)


def pick_window(windows: Windows, track: int, t0_ns: int, recording: str | None, source: Path) -> int:
    """Index of the window of ``track`` (in ``recording``) whose t0 is within half a frame of ``t0_ns``."""
    import numpy as np

    index = windows.index
    ok = index.column("track_id").to_numpy() == track
    rec = index.column("recording").to_numpy(zero_copy_only=False).astype(str)
    if recording is not None:
        ok &= rec == recording
    if not ok.any():
        where = f" in {recording}" if recording else ""
        raise InputError(
            source,
            f"--track {track} --time {t0_ns / 1e9:g}: no window of track {track}{where} at t0 = {t0_ns / 1e9:.1f} s",
            expected="a track present in INPUT with 3 s of history up to t0",
        )
    t0 = index.column("t0_ns").to_numpy()
    near = ok & (np.abs(t0 - t0_ns) <= STEP_NS // 2)
    if not near.any():
        nearest = nearest_on_stride(t0[ok], t0_ns)
        if nearest is None:
            times = t0[ok] / 1e9
            raise InputError(
                source,
                f"--time {t0_ns / 1e9:g}: track {track} has no window at t0 = {t0_ns / 1e9:.1f} s",
                expected=f"a time with 3 s of history: {times.min():.1f} … {times.max():.1f} s",
            )
        best, stride = nearest
        print(
            f"lanecast explain: {source} has windows of track {track} every {stride / 1e9:.1f} s; "
            f"the nearest to {t0_ns / 1e9:.1f} s is at {best / 1e9:.1f} s",
            file=sys.stderr,
        )
        near = ok & (t0 == best)
    found = np.flatnonzero(near)
    if len(set(rec[found])) > 1:
        raise InputError(
            source,
            f"--track {track}: the track is in several recordings: {sorted(set(rec[found]))}",
            expected="--recording naming one of them",
        )
    return int(found[0])


def nearest_on_stride(t0: np.ndarray, t0_ns: int) -> tuple[int, int] | None:
    """(the window t0 nearest to ``t0_ns``, the stride), both ns, when ``t0_ns`` lies between two of
    a track's window times ``t0`` [M] no more than one stride apart (a dataset cut with
    ``--stride``), else None."""
    import numpy as np

    times = np.unique(t0)
    after = int(np.searchsorted(times, t0_ns))
    if after == 0 or after == len(times):
        return None
    before_t, after_t = int(times[after - 1]), int(times[after])
    stride = int(np.median(np.diff(times)))
    if after_t - before_t > stride:  # a gap in the track: no window there
        return None
    return (before_t if t0_ns - before_t <= after_t - t0_ns else after_t), stride


def window_of(args: argparse.Namespace, card: dict[str, Any]) -> tuple[Windows, int]:
    """The windows INPUT gives (a dataset as it is, or cut at --time from a table or log) and the index of
    the target's window."""
    import numpy as np

    from lanecast.io_adapters.contracts.windows import DATASET_FILES
    from lanecast.io_adapters.windows_store.dataset import load_windows
    from lanecast.pipeline.make_windows import make_windows
    from lanecast.pipeline.neighbour_columns import NEIGHBOUR_RANGE_M

    t0_ns = round(args.time * 10) * STEP_NS
    # A directory with any file of a windows dataset is one: one missing is load_windows' to name
    # (not read as a Parquet track table dataset of its windows.parquet).
    if args.input.is_dir() and any((args.input / name).exists() for name in DATASET_FILES):
        windows = load_windows(args.input)
    else:
        table = registry.read_any([args.input])
        neighbour_range = (card.get("windows") or {}).get("neighbour_range_m") or NEIGHBOUR_RANGE_M
        windows = make_windows(
            table,
            require_future=False,
            split="none",
            t0_ns=np.array([t0_ns], np.int64),
            allow_empty=True,
            neighbour_range=float(neighbour_range),
        )
        try:
            return windows, pick_window(windows, args.track, t0_ns, args.recording, args.input)
        except InputError as exc:
            raise no_window_in_table(table, args.track, t0_ns, args.recording, args.input) from exc
    return windows, pick_window(windows, args.track, t0_ns, args.recording, args.input)


def no_window_in_table(
    table: pa.Table, track: int, t0_ns: int, recording: str | None, source: Path
) -> InputError:
    """Why a table or log has no window of ``track`` at ``t0_ns``, with the times it has one at
    (a log's clock is its own: the --help example's time is no time in another log)."""
    import pyarrow.compute as pc

    from lanecast.io_adapters.contracts.windows import HISTORY

    rows = pc.equal(table.column("track_id"), track)
    if recording is not None:
        rows = pc.and_(rows, pc.equal(table.column("recording"), recording))
    times = table.column("time_ns").filter(rows)
    where = f" in {recording}" if recording else ""
    if len(times) == 0:
        ids = table.column("track_id")
        return InputError(
            source,
            f"--track {track}: no track {track}{where}",
            expected=f"a track id of INPUT ({pc.min(ids).as_py()} … {pc.max(ids).as_py()}; `lanecast info` lists them)",
        )
    first, last = pc.min(times).as_py() / 1e9, pc.max(times).as_py() / 1e9
    history_s = (HISTORY - 1) * STEP_NS / 1e9
    span = f"it is in INPUT from {first:.1f} to {last:.1f} s"
    if last - first < history_s:
        return InputError(
            source,
            f"--track {track}: track {track}{where} has no window: {span}, less than the 3 s of history a window needs",
            expected="a track in INPUT for 3 s or more",
        )
    return InputError(
        source,
        f"--time {t0_ns / 1e9:g}: track {track}{where} has no window at t0 = {t0_ns / 1e9:.1f} s: {span}",
        expected=f"a time after 3 s of gap-free history: {first + history_s:.1f} … {last:.1f} s",
    )


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from lanecast.io_adapters.files import check_output_dir, staged_files
    from lanecast.models.explain import parse_removals, present_neighbours, what_if
    from lanecast.models.reports.explain import write_explain
    from lanecast.models.runtime import load_forecaster

    check_output_dir(args.out, files=("explain.json", "explain.html"), force=args.force)  # before the work
    forecaster = load_forecaster(args.model)
    card: dict[str, Any] = getattr(forecaster, "card", None) or {}
    windows, i = window_of(args, card)
    inputs, present = np.asarray(windows.inputs[i]), np.asarray(windows.present[i])
    try:
        removals = parse_removals(args.remove, present) if args.remove else []
    except InputError as exc:
        raise exc.naming(args.input) from None
    if args.all or not args.remove:
        removals += [(n,) for n in present_neighbours(present) if (n,) not in removals]
    if not removals:
        raise InputError(args.input, "the target has no neighbour in this window: nothing to remove")
    with activity(f"explain: forecasts with {len(removals)} neighbour removal(s)"):
        whatif = what_if(forecaster, inputs, present, removals, top_k=args.top_k)
    row = windows.index.slice(i, 1).to_pylist()[0]
    window = {
        "source": str(args.input),
        "recording": row["recording"],
        "track_id": int(row["track_id"]),
        "t0_s": row["t0_ns"] / 1e9,
        "neighbours": present_neighbours(present),
    }
    model = provenance_line(provenance(args.model)).removeprefix("model: ")
    with staged_files(args.out, force=args.force) as stage:  # an interrupted run leaves none of its files
        with activity("explain: drawing the scenes"):
            page = write_explain(stage, whatif, window, model, np.asarray(windows.future[i]))
    page = args.out / page.relative_to(stage)
    effects = {e["scenario"]: e for e in whatif.effects()}
    print(
        f"{window['recording']} track {window['track_id']} at t0 = {window['t0_s']:.1f} s; most influential first:"
    )
    for s in whatif.rank():
        e = effects[whatif.names[s]]
        dp = (
            ""
            if e["max_probability_change"] is None
            else f", probabilities up to {e['max_probability_change']:.2f}"
        )
        print(
            f"  {whatif.names[s]:<22} forecast moved {e['mean_shift_m']:.2f} m (5 s: {e['shift_5s_m']:.2f} m){dp}"
        )
    print(f"wrote {page}")
    return 0
