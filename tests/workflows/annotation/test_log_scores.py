"""Log scores read the forecasts of annotated logs: bad prediction documents are named at their
message and field, forecasts of another layout or time are refused, the data section is read
rather than a lying chunk index."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import pytest
from conftest import OP_CHUNK_INDEX, _prediction_doc, chunks, fix_crcs
from conftest import mcap_record_spans as records

from lanecast.io_adapters.errors import LogError
from lanecast.workflows.cli import main


def test_report_reads_the_forecasts_of_the_data_section_not_of_a_lying_chunk_index(tmp_path: Path) -> None:
    """An annotated log whose second chunk index points at the first chunk (CRCs recomputed): the
    report's mcap reader seeks by the index, so it read the first forecast twice and never the
    second, scoring other forecasts than the log holds without a word. The documents are now read
    from the data section in file order."""
    import json

    from conftest import _prediction_doc
    from mcap.writer import CompressionType, Writer

    from lanecast.workflows.annotation.log_scores import prediction_documents

    log = tmp_path / "annotated.mcap"
    with log.open("wb") as f:
        w = Writer(f, chunk_size=64, compression=CompressionType.NONE, enable_data_crcs=True)
        w.start()
        cid = w.register_channel("/lanecast/prediction", "json", 0)
        for i in range(4):
            doc = {**_prediction_doc(), "t0_ns": (i + 1) * 10**9}
            w.add_message(cid, log_time=(i + 1) * 10**9, data=json.dumps(doc).encode(), publish_time=0)
        w.finish()
    d = bytearray(log.read_bytes())
    first, second = chunks(bytes(d))[:2]
    at = [o for o, op, _ in records(bytes(d)) if op == OP_CHUNK_INDEX][1]
    assert struct.unpack_from("<Q", d, at + 9 + 16)[0] == second
    struct.pack_into("<Q", d, at + 9 + 16, first)
    fix_crcs(d)
    log.write_bytes(bytes(d))
    docs = prediction_documents(log)
    assert [doc["t0_ns"] for doc in docs] == [10**9, 2 * 10**9, 3 * 10**9, 4 * 10**9]


def _prediction_log(path: Path, docs: list[tuple[int, dict[str, Any]]]) -> Path:
    """An MCAP of /lanecast/prediction JSON documents at the given log times."""
    import json

    from mcap.writer import Writer

    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        cid = w.register_channel("/lanecast/prediction", "json", 0)
        for log_time, doc in docs:
            w.add_message(cid, log_time=log_time, data=json.dumps(doc).encode(), publish_time=log_time)
        w.finish()
    return path


@pytest.mark.parametrize(
    ("edit", "column", "says"),
    [
        (
            lambda d: d.update(horizon_s=[0.5, 1, 1.5, 2, 2.5]),
            "horizon_s",
            "horizon_s is [0.5, 1, 1.5, 2, 2.5]",
        ),
        (
            lambda d: d.update(maneuver_names=["a", "b", "c"]),
            "maneuver_names",
            "maneuver_names is ['a', 'b', 'c']",
        ),
    ],
)
def test_a_forecast_of_another_layout_is_refused_not_scored(
    tmp_path: Path, edit: Any, column: str, says: str
) -> None:
    """A /lanecast/prediction document whose horizons or maneuver names are not lanecast's: the
    report scored its five points as 1-5 s and its classes as straight/left/right, exit 0."""
    from conftest import _prediction_doc

    from lanecast.workflows.annotation.log_scores import prediction_documents

    good = _prediction_doc()
    bad = _prediction_doc()
    edit(bad)
    log = _prediction_log(tmp_path / "layout.mcap", [(good["t0_ns"], good), (bad["t0_ns"], bad)])
    with pytest.raises(LogError) as err:
        prediction_documents(log)
    assert err.value.column == column and err.value.path == str(log)
    assert f"/lanecast/prediction message 2 (log time {bad['t0_ns']} ns): {says}" in str(err.value)


def test_report_refuses_a_forecast_logged_at_another_time_than_its_t0(tmp_path: Path) -> None:
    """A document whose t0_ns is not its message's log time (edited, or one second off): the
    report scored it against the windows at t0_ns, other than the ones it was made for, exit 0;
    and a log whose every forecast has no targets was a ValueError traceback ('axes don't match')."""
    from conftest import _prediction_doc

    from lanecast.io_adapters.errors import InputError
    from lanecast.workflows.annotation.log_scores import checked_forecast_times, prediction_documents

    doc = _prediction_doc()
    log = _prediction_log(tmp_path / "shifted.mcap", [(doc["t0_ns"], doc), (doc["t0_ns"] - 10**9, doc)])
    with pytest.raises(LogError) as err:
        checked_forecast_times(log, prediction_documents(log))
    assert err.value.column == "t0_ns" and str(
        f"/lanecast/prediction message 2 (log time {doc['t0_ns'] - 10**9} ns): t0_ns {doc['t0_ns']} is not "
        "the message's log time"
    ) in str(err.value)
    empty = _prediction_log(tmp_path / "empty.mcap", [(doc["t0_ns"], {**doc, "targets": []})] * 3)
    with pytest.raises(InputError, match="the 3 forecasts on /lanecast/prediction have no targets"):
        prediction_documents(empty)
    assert main(["report", str(empty), "--out", str(tmp_path / "r")]) == 2
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    ("edit", "column", "expected"),
    [
        (lambda d: d["targets"][0].update(x=[1.0, 2.0, 3.0, 4.0]), "targets[0].x", "5 finite numbers"),
        (lambda d: d["targets"][0]["y"].__setitem__(2, None), "targets[0].y", "5 finite numbers"),
        (lambda d: d.pop("targets"), "targets", "a list"),
        (lambda d: d["targets"][0].update(track_id="car-7"), "targets[0].track_id", "an integer"),
        (lambda d: d.update(t0_ns="soon"), "t0_ns", "an integer (ns)"),
        (lambda d: d["targets"][0].update(maneuver_probs=[[1, 0]]), "targets[0].maneuver_probs", "null or 5"),
        (
            lambda d: d["targets"][0]["alternatives"][0].pop("x"),
            "targets[0].alternatives[0]",
            "an object with",
        ),
        # fuzz seeds 1131 and 1134: 1e308 was taken in, and the report was a traceback
        (lambda d: d["targets"][0]["y"].__setitem__(1, 1e308), "targets[0].y", "5 finite numbers within"),
        (
            lambda d: d["targets"][0]["maneuver_probs"][2].__setitem__(0, 1e308),
            "targets[0].maneuver_probs",
            "null or 5 lists of 3 numbers from 0 to 1",
        ),
        (
            lambda d: d["targets"][0]["maneuver_probs"][0].__setitem__(1, -0.5),
            "targets[0].maneuver_probs",
            "null or 5",
        ),
        (
            lambda d: d["targets"][0]["alternatives"][0].update(prob=7),
            "targets[0].alternatives[0].prob",
            "a number",
        ),
        (lambda d: d["targets"][0].update(origin=[1e300, 0.0]), "targets[0].origin", "null or 2 finite"),
    ],
)
def test_a_bad_prediction_document_names_its_message_and_field(
    tmp_path: Path, edit: object, column: str, expected: str
) -> None:
    """`lanecast report` on a log whose /lanecast/prediction JSON has a field of the wrong shape or
    type (4 points, a null coordinate, no targets, a string track id): a ValueError/KeyError/
    TypeError traceback, or (a null point) NaN taken into the metrics; now the message, its log
    time and the field."""
    import json

    from mcap.writer import Writer

    from lanecast.workflows.annotation.log_scores import prediction_documents

    bad = _prediction_doc()
    edit(bad)  # type: ignore[operator]
    log = tmp_path / "annotated.mcap"
    with log.open("wb") as f:
        w = Writer(f)
        w.start()
        cid = w.register_channel("/lanecast/prediction", "json", 0)
        for i, doc in enumerate([_prediction_doc(), bad]):
            w.add_message(cid, log_time=(i + 1) * 10**9, data=json.dumps(doc).encode(), publish_time=0)
        w.finish()
    with pytest.raises(LogError, match=r"/lanecast/prediction message 2 \(log time 2000000000 ns\)") as err:
        prediction_documents(log)
    assert err.value.path == str(log) and err.value.column == column
    assert (err.value.expected or "").startswith(expected)
