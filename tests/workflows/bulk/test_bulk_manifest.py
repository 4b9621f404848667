"""Bulk annotation's inputs and its OUT_DIR/manifest.jsonl in unusual but legitimate forms (linked
folders, a manifest saved by an editor) and hostile ones (a FIFO, a damaged entry): read as meant,
or one clear error naming the file; never a traceback or a hang."""

from __future__ import annotations

import json
import os
import stat
import threading
from collections.abc import Callable
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from conftest import (
    assert_one_line_error,
    cli,
    forecasts_for,
    json_log,
    make_mcap,
    refused,
    straight_messages,
)

from lanecast.io_adapters.errors import InputError
from lanecast.workflows.annotation.annotate_log import AnnotateOptions
from lanecast.workflows.bulk.manifest import MANIFEST, Manifest
from lanecast.workflows.bulk.runner import LOCK, run_bulk
from lanecast.workflows.cli import main


def _log(folder: Path, name: str, fc: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    fc.mkdir(exist_ok=True)
    pq.write_table(forecasts_for(name, [1], [1]), fc / f"{name}.parquet")
    return make_mcap(folder / f"{name}.mcap", n=20)


def test_logs_in_a_linked_folder_or_linked_in_from_elsewhere_are_annotated(tmp_path: Path) -> None:
    """A folder reached through a symbolic link (``data -> /mnt/disk/data``), or a log linked into
    the folder from elsewhere, failed with a ValueError traceback ('... is not in the subpath of
    ...'): logs were named by where the links lead, outside the folder given."""
    fc = tmp_path / "fc"
    _log(tmp_path / "disk" / "logs", "a", fc)
    (tmp_path / "data").symlink_to(tmp_path / "disk" / "logs")
    (tmp_path / "elsewhere").mkdir()
    _log(tmp_path / "elsewhere", "b", fc)
    (tmp_path / "disk" / "logs" / "b.mcap").symlink_to(tmp_path / "elsewhere" / "b.mcap")
    out = tmp_path / "out"
    result = run_bulk([tmp_path / "data"], out, AnnotateOptions(forecasts=fc))
    assert len(result.done) == 2 and sorted(p.name for p in out.glob("*.mcap")) == ["a.mcap", "b.mcap"]
    again = run_bulk([tmp_path / "disk" / "logs"], out, AnnotateOptions(forecasts=fc))  # the same logs
    assert len(again.skipped) == 2 and not again.entries


def _returns(action: Callable[[], object]) -> BaseException | None:
    """What ``action`` raised (None if nothing), run in a daemon thread: a test of code that blocks
    on a FIFO fails after a minute instead of hanging the suite."""
    raised: list[BaseException | None] = []

    def run() -> None:
        try:
            action()
            raised.append(None)
        except BaseException as exc:
            raised.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(60.0)
    assert raised, "blocked opening a FIFO"
    return raised[0]


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_a_manifest_that_is_a_fifo_or_a_device_is_refused_unopened(tmp_path: Path, kind: str) -> None:
    """OUT_DIR/manifest.jsonl as a FIFO blocked `lanecast annotate` for ever (opened to be read
    before its type was looked at); now refused at once as no regular file, for reading and for
    appending."""
    manifest = Manifest(tmp_path)
    if kind == "fifo":
        os.mkfifo(manifest.path)
    else:
        if os.geteuid() != 0:
            pytest.skip("making a device node needs root")
        os.mknod(manifest.path, 0o600 | stat.S_IFCHR, os.makedev(1, 3))  # /dev/null
    for action in (manifest.entries, lambda: manifest.append({"input": "/a", "status": "started"})):
        err = _returns(action)
        assert isinstance(err, InputError), err
        assert err.path == str(tmp_path / MANIFEST) and "not a regular file" in str(err)


def test_a_lock_file_that_is_a_fifo_is_refused_unopened(tmp_path: Path) -> None:
    """OUT_DIR/.lanecast-annotate.lock as a FIFO blocked `lanecast annotate` for ever (opened for
    writing, which waits for a reader); now refused at once, naming it."""
    fc = tmp_path / "fc"
    log = _log(tmp_path / "logs", "a", fc)
    out = tmp_path / "out"
    out.mkdir()
    os.mkfifo(out / LOCK)
    err = _returns(lambda: run_bulk([log], out, AnnotateOptions(forecasts=fc)))
    assert isinstance(err, InputError), err
    assert err.path == str(out / LOCK) and "not a regular file" in str(err)
    assert sorted(p.name for p in out.iterdir()) == [LOCK]  # nothing written


def test_a_manifest_saved_by_an_editor_is_read_as_written(tmp_path: Path) -> None:
    """A manifest re-saved by an editor (a byte order mark, CRLF, blank and comment lines), with an
    integer of 5,000 digits on one line, or an output recorded absolute inside OUT_DIR: the BOM
    hid the first entry (its log redone, or its output refused as not lanecast's), the long integer
    was a ValueError traceback, and the absolute output was not the relative name the rest of
    the manifest uses (the output refused as written by someone else)."""
    out = tmp_path / "out"
    out.mkdir()
    lines = [
        '{"input": "/logs/a.mcap", "output": "a.mcap", "status": "done"}',
        "",
        "# re-saved by hand",
        '{"input": "/logs/x.mcap", "output": "x.mcap", "status": "done", "n": ' + "9" * 5000 + "}",
        f'{{"input": "/logs/b.mcap", "output": "{out / "day 2" / "b.mcap"}", "status": "done"}}',
    ]
    (out / MANIFEST).write_bytes(b"\xef\xbb\xbf" + "\r\n".join(lines).encode() + b"\r\n")
    assert Manifest(out).claims() == {"a.mcap": "/logs/a.mcap", "day 2/b.mcap": "/logs/b.mcap"}


@pytest.mark.parametrize("output", [5, ["a.mcap"], "."])
def test_report_on_a_manifest_entry_naming_no_output_file_names_the_manifest(
    tmp_path: Path, output: object
) -> None:
    """`lanecast report OUT_DIR` whose manifest has a done entry with a number or a list as its
    output was a TypeError traceback; '.' read OUT_DIR itself as a log. Now refused naming the
    manifest and the entry's input."""
    from lanecast.workflows.annotation.log_scores import annotated_logs

    out = tmp_path / "out"
    out.mkdir()
    entry = {"input": "/logs/a.mcap", "output": output, "status": "done"}
    (out / MANIFEST).write_text(json.dumps(entry) + "\n")
    with pytest.raises(InputError) as err:
        annotated_logs([out])
    assert err.value.path == str(out / MANIFEST) and "'/logs/a.mcap' names no output file" in str(err.value)


def test_a_long_manifest_is_parsed_once_per_change(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A rerun reads the manifest for the finished entries, for the output claims and again for
    the outputs to refuse: three parses of every line (about 4 s each for 200,000 entries, 127 MB).
    It is parsed again only after it changed."""
    manifest = Manifest(tmp_path)
    for i in range(50):
        manifest.append({"input": f"/logs/{i}.mcap", "output": f"{i}.mcap", "status": "done"})
    parsed = []
    loads = json.loads
    monkeypatch.setattr(json, "loads", lambda text: parsed.append(text) or loads(text))
    assert len(manifest.finished()) == len(manifest.claims()) == len(manifest.latest()) == 50
    assert len(parsed) == 50
    manifest.append({"input": "/logs/new.mcap", "output": "new.mcap", "status": "started"})
    assert len(manifest.claims()) == 51 and len(parsed) == 50 + 51


def test_an_output_name_with_a_nul_byte_is_no_claim(tmp_path: Path) -> None:
    """A done entry whose output holds a NUL byte (a damaged manifest) was taken as the log's output
    name: the log failed with a bare 'ValueError: embedded null byte' naming no file. Such a name
    is no claim: the log is annotated under its own name."""
    fc = tmp_path / "fc"
    log = _log(tmp_path / "logs", "a", fc)
    out = tmp_path / "out"
    out.mkdir()
    entry = {"input": str(log.resolve()), "output": "a\0.mcap", "status": "done", "output_sha256": "0"}
    (out / MANIFEST).write_text(json.dumps(entry) + "\n")
    result = run_bulk([tmp_path / "logs"], out, AnnotateOptions(forecasts=fc))
    assert len(result.done) == 1 and (out / "a.mcap").is_file()


@pytest.mark.parametrize(
    ("claimed", "refused"),
    [("../logs/a.mcap", True), ("ABSOLUTE-INPUT", True), ("b.mcap", False), ("~/a.mcap", False)],
)
def test_an_entry_naming_another_output_keeps_input_and_output_and_names_the_manifest(
    tmp_path: Path, claimed: str, refused: bool
) -> None:
    """A manifest whose entry for a.mcap names another output, run from another folder: one
    outside OUT_DIR (the input itself, ``..``) is not lanecast's to write, so out/a.mcap, which
    the manifest no longer records, is kept and the refusal names the manifest, which holds the
    cause (before: it named only out/a.mcap, 'not written by lanecast annotate'); a name inside
    OUT_DIR (``b.mcap``, a literal ``~`` folder) is written there. The input is never touched and
    nothing is written outside OUT_DIR (``~`` is not the home folder)."""
    fc = tmp_path / "fc"
    log = _log(tmp_path / "logs", "a", fc)
    out = tmp_path / "out"
    run_bulk([tmp_path / "logs"], out, AnnotateOptions(forecasts=fc))
    manifest = out / MANIFEST
    entries = [json.loads(line) for line in manifest.read_text().splitlines()]
    for entry in entries:
        entry["output"] = str(log) if claimed == "ABSOLUTE-INPUT" else claimed
    manifest.write_text("".join(json.dumps(e) + "\n" for e in entries))
    before = {p: p.read_bytes() for p in (log, out / "a.mcap")}
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    cwd = Path.cwd()
    os.chdir(elsewhere)
    try:
        if refused:
            with pytest.raises(InputError) as err:
                run_bulk([Path("../logs")], Path("../out"), AnnotateOptions(forecasts=Path("../fc")))
            assert "not written by lanecast annotate" in str(err.value) and MANIFEST in str(err.value)
        else:
            result = run_bulk([Path("../logs")], Path("../out"), AnnotateOptions(forecasts=Path("../fc")))
            assert len(result.done) == 1 and (out / claimed).is_file()
    finally:
        os.chdir(cwd)
    assert {p: p.read_bytes() for p in before} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere", "fc", "logs", "out"]
    assert not list(elsewhere.iterdir()) and not (Path.home() / "a.mcap").exists()


def test_a_manifest_that_is_a_directory_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """OUT_DIR/manifest.jsonl being a directory was reported as '4: Is a directory' (a file
    descriptor for a file name)."""
    from conftest import forecasts_for, make_mcap

    log = make_mcap(tmp_path / "drive.mcap", n=60)
    fc = tmp_path / "fc.parquet"
    pq.write_table(forecasts_for("drive", [1, 2], [1, 2]), fc)
    out = tmp_path / "ann"
    (out / "manifest.jsonl").mkdir(parents=True)
    refused(
        ["annotate", str(log), "--forecasts", str(fc), "--out", str(out)],
        capsys,
        f"{out / 'manifest.jsonl'}: not a regular file",
    )


# ------------------------------------------------------------------------- the output directory


def test_planted_lock_and_manifest_symlinks_touch_nothing_outside(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = json_log(tmp_path / "in.mcap", straight_messages(n=60))
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / ".lanecast-annotate.lock").symlink_to(victim)
    status, err = cli(["annotate", str(log), "--out", str(out)], capsys)
    assert_one_line_error(status, err, "annotate", ".lanecast-annotate.lock")
    assert "symlink" in err and victim.read_text() == "precious\n"
    (out / ".lanecast-annotate.lock").unlink()
    (out / "manifest.jsonl").symlink_to(victim)
    status, err = cli(["annotate", str(log), "--out", str(out)], capsys)
    assert_one_line_error(status, err, "annotate", "manifest.jsonl")
    assert victim.read_text() == "precious\n"


def test_forged_manifest_entry_does_not_skip_a_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = json_log(tmp_path / "in.mcap", straight_messages(n=60))
    out = tmp_path / "out"
    assert main(["annotate", str(log), "--out", str(out)]) == 0
    capsys.readouterr()
    manifest = out / "manifest.jsonl"

    def done() -> list[dict[str, object]]:
        return [e for e in map(json.loads, manifest.read_text().splitlines()) if e["status"] == "done"]

    (entry,) = done()
    assert isinstance(entry["output_sha256"], str)
    # a second run skips the log: its output is there with the recorded checksum
    lines = manifest.read_text()
    assert main(["annotate", str(log), "--out", str(out)]) == 0
    assert manifest.read_text() == lines
    # a forged line: the output is elsewhere (a system file), size and mtime as recorded
    outside = tmp_path / "system-file"
    outside.write_bytes((out / "in.mcap").read_bytes())
    planted = outside.stat().st_mtime_ns
    (out / "in.mcap").unlink()
    forged = {**entry, "output": str(outside)}
    manifest.write_text(json.dumps(forged) + "\n")
    assert main(["annotate", str(log), "--out", str(out)]) == 0
    assert (out / "in.mcap").is_file() and len(done()) == 2
    assert outside.stat().st_mtime_ns == planted  # a forged name is never written to
    # an output changed since it was recorded is redone
    data = bytearray((out / "in.mcap").read_bytes())
    data[100] ^= 1
    (out / "in.mcap").write_bytes(bytes(data))
    assert main(["annotate", str(log), "--out", str(out)]) == 0
    assert len(done()) == 3
    assert (out / "in.mcap").read_bytes() != bytes(data)
