"""Bulk annotation: manifest, resume after failure and after SIGKILL, worker processes, Ray.

The logs are real MCAP files (conftest.make_mcap) with precomputed forecasts tables
(``--forecasts DIR``), so that these tests exercise the runner and not the model.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from conftest import REPO, assert_all_original_records_equal, forecasts_for, make_mcap
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import checksum
from lanecast.workflows.annotation.annotate_log import AnnotateOptions
from lanecast.workflows.annotation.log_scores import annotated_logs
from lanecast.workflows.bulk.discovery import discover, plan_outputs
from lanecast.workflows.bulk.manifest import Manifest
from lanecast.workflows.bulk.runner import clean_temporaries, run_bulk


def make_fleet(root: Path, n: int, *, messages: int = 200, payload: int = 16) -> tuple[Path, Path]:
    """``n`` logs under root/logs (two in a sub-directory) and their forecasts under root/forecasts."""
    logs, fc = root / "logs", root / "forecasts"
    (logs / "day2").mkdir(parents=True)
    fc.mkdir()
    for i in range(n):
        name = f"log{i:02d}"
        folder = logs / "day2" if i >= n - 2 else logs
        make_mcap(folder / f"{name}.mcap", n=messages, payload=payload)
        pq.write_table(forecasts_for(name, [1, 2, 3], [1, 2]), fc / f"{name}.parquet")
    return logs, fc


def forecast_count(path: Path) -> int:
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages(topics=["/lanecast/forecast"]))


def test_discover_walks_directories_and_names_outputs_uniquely(tmp_path: Path) -> None:
    logs, _ = make_fleet(tmp_path, 3, messages=20)
    (logs / "notes.txt").write_text("not a log")
    out = logs / "annotated"  # an OUT_DIR inside the input directory is never read as input
    out.mkdir()
    make_mcap(out / "log00.mcap", n=5)
    make_mcap(tmp_path / "log00.mcap", n=5)  # same name as logs/log00.mcap
    found = discover([logs, tmp_path / "log00.mcap"], exclude=out)
    assert [p.relative_to(tmp_path).as_posix() for p in found] == [
        "logs/day2/log01.mcap",
        "logs/day2/log02.mcap",
        "logs/log00.mcap",
        "log00.mcap",
    ]
    names = [t.output.relative_to(out).as_posix() for t in plan_outputs(found, out)]
    assert names == ["logs/day2/log01.mcap", "logs/day2/log02.mcap", "logs/log00.mcap", "log00.mcap"]
    names = [t.output.relative_to(out).as_posix() for t in plan_outputs(found[:3], out)]
    assert names == ["day2/log01.mcap", "day2/log02.mcap", "log00.mcap"]


def test_rerun_skips_done_retries_failed_and_redoes_changed_inputs(tmp_path: Path) -> None:
    logs, fc = make_fleet(tmp_path, 3, messages=50)
    bad = logs / "broken.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)  # a header that is not there
    pq.write_table(forecasts_for("broken", [1], [1]), fc / "broken.parquet")
    out = tmp_path / "out"
    opts = AnnotateOptions(forecasts=fc)

    first = run_bulk([logs], out, opts)
    assert (len(first.done), len(first.failed), len(first.skipped)) == (3, 1, 0)
    assert "broken.mcap" in first.failed[0]["error"]
    entries = Manifest(out).entries()
    assert [e["status"] for e in entries].count("done") == 3
    done = next(e for e in entries if e["input"].endswith("log00.mcap") and e["status"] == "done")
    assert done["sha256"] == checksum(logs / "log00.mcap")
    assert done["counts"]["added"] == 6 and done["counts"]["messages"] == 50 + 5 + 8
    assert done["output"] == "log00.mcap" and forecast_count(out / "log00.mcap") == 3

    second = run_bulk([logs], out, opts)  # done logs skipped, the bad one retried (and fails again)
    assert (len(second.done), len(second.failed), len(second.skipped)) == (0, 1, 3)

    make_mcap(bad, n=30)  # repaired
    make_mcap(logs / "log00.mcap", n=31)  # changed since it was annotated
    third = run_bulk([logs], out, opts)
    assert sorted(Path(e["input"]).name for e in third.done) == ["broken.mcap", "log00.mcap"]
    assert len(third.skipped) == 2
    latest = Manifest(out).latest()
    assert {Path(k).name: v["status"] for k, v in latest.items()} == dict.fromkeys(
        ["broken.mcap", "log00.mcap", "log01.mcap", "log02.mcap"], "done"
    )
    assert_all_original_records_equal(logs / "log00.mcap", out / "log00.mcap")


def test_relative_out_resumes_and_reports_from_another_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The manifest's paths resolve the same from anywhere: a rerun of the same relative command from
    another directory redoes nothing, and `report` finds the outputs the manifest names."""
    _, fc = make_fleet(tmp_path, 2, messages=30)
    (tmp_path / "a" / "b").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "a")
    first = run_bulk([Path("../logs")], Path("out"), AnnotateOptions(forecasts=fc))
    assert len(first.done) == 2 and (tmp_path / "a" / "out" / "day2" / "log00.mcap").is_file()
    entries = Manifest(tmp_path / "a" / "out").entries()
    assert {e["output"] for e in entries} == {"day2/log00.mcap", "day2/log01.mcap"}

    monkeypatch.chdir(tmp_path / "a" / "b")
    again = run_bulk([Path("../../logs")], Path("../out"), AnnotateOptions(forecasts=fc))
    assert len(again.skipped) == 2 and not again.entries
    assert Manifest(tmp_path / "a" / "out").entries() == entries  # nothing written: nothing redone

    monkeypatch.chdir(tmp_path)
    found = annotated_logs([Path("a/out")])
    assert found == [Path("a/out/day2/log00.mcap"), Path("a/out/day2/log01.mcap")]
    assert all(p.is_file() for p in found)


def test_manifest_survives_a_line_cut_short_and_temporaries_are_cleaned(tmp_path: Path) -> None:
    m = Manifest(tmp_path)
    m.append({"input": "/a", "status": "done"})
    with open(m.path, "a") as f:
        f.write('{"input": "/b", "sta')  # a kill in the middle of a write
    m.append({"input": "/c", "status": "failed"})
    assert [e["input"] for e in m.entries()] == ["/a", "/c"]
    assert all(e["v"] == 2 for e in m.entries())
    (tmp_path / ".x.mcap.tmp-abc").write_bytes(b"half")
    (tmp_path / ".bag.tmp-def").mkdir()
    (tmp_path / "keep.mcap").write_bytes(b"whole")
    assert sorted(p.name for p in clean_temporaries(tmp_path)) == [".bag.tmp-def", ".x.mcap.tmp-abc"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.mcap", "manifest.jsonl"]


@pytest.mark.slow
def test_two_worker_processes_annotate_every_log_once(tmp_path: Path) -> None:
    logs, fc = make_fleet(tmp_path, 4, messages=40)
    out = tmp_path / "out"
    result = run_bulk([logs], out, AnnotateOptions(forecasts=fc), workers=2)
    assert len(result.done) == 4 and not result.failed
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        "day2",
        "day2/log02.mcap",
        "day2/log03.mcap",
        "log00.mcap",
        "log01.mcap",
        "manifest.jsonl",
    ]
    for i in range(4):
        sub = "day2/" if i >= 2 else ""
        assert_all_original_records_equal(logs / f"{sub}log{i:02d}.mcap", out / f"{sub}log{i:02d}.mcap")


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "lanecast.workflows.cli", "annotate", *args]


# The real command, paused inside the copy of its third log until it is killed: the kill lands
# mid-log at a known point (two logs done) instead of racing a poll against the run.
_PAUSE_IN_THIRD_LOG = """
import sys, time
from pathlib import Path
from lanecast.io_adapters.logs.mcap import copy as mcap_copy
from lanecast.workflows.cli import main
ready, copy_mcap, calls = Path(sys.argv[1]), mcap_copy.copy_mcap, []
def pausing_copy(src, out, *args):
    calls.append(src)
    if len(calls) == 3:
        out.write(b"half a log")
        ready.write_text(str(src))
        time.sleep(600)
    return copy_mcap(src, out, *args)
mcap_copy.copy_mcap = pausing_copy
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow
def test_sigkill_mid_run_then_rerun_annotates_every_log_exactly_once(tmp_path: Path) -> None:
    n = 8
    logs, fc = make_fleet(tmp_path, n, messages=600, payload=200)
    out = tmp_path / "out"
    args = _cli(str(logs), "--out", str(out), "--forecasts", str(fc))
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    ready = tmp_path / "paused"
    paused = [sys.executable, "-c", _PAUSE_IN_THIRD_LOG, str(ready), *args[3:]]
    proc = subprocess.Popen(paused, cwd=REPO, env=env, start_new_session=True, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and not ready.exists():
        time.sleep(0.1)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    killed_with = sum(e["status"] == "done" for e in Manifest(out).entries())
    assert 2 <= killed_with < n

    rerun = subprocess.run(args, cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert rerun.returncode == 0, rerun.stderr
    assert f"{killed_with} already done" in rerun.stdout
    entries = [e for e in Manifest(out).entries() if e["status"] != "started"]
    assert all(e["status"] == "done" for e in entries)
    per_input = [Path(e["input"]).name for e in entries]
    assert sorted(per_input) == sorted(f"log{i:02d}.mcap" for i in range(n))  # each exactly once
    assert sorted(p.name for p in out.rglob("*.mcap")) == sorted(f"log{i:02d}.mcap" for i in range(n))
    assert not [p for p in out.rglob("*") if ".tmp-" in p.name]
    for i in range(n):
        assert forecast_count(out / ("day2/" if i >= n - 2 else "") / f"log{i:02d}.mcap") == 3


def test_bad_input_list_is_reported_clearly(tmp_path: Path) -> None:
    result = subprocess.run(
        _cli(str(tmp_path / "nope"), "--out", str(tmp_path / "o")),
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert "nope: no such file or directory" in result.stderr and "Traceback" not in result.stderr


def _tree(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*.mcap"))}


@pytest.mark.slow
def test_ray_on_a_local_cluster_writes_what_the_process_pool_writes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Byte-identical outputs; a relative --out lands where the driver asked, not in the workers'
    working directory; a rerun on Ray skips everything."""
    pytest.importorskip("ray")
    logs, fc = make_fleet(tmp_path, 3, messages=30)
    pool = run_bulk([logs], tmp_path / "pool", AnnotateOptions(forecasts=fc), workers=2)
    assert len(pool.done) == 3
    monkeypatch.chdir(tmp_path)
    result = run_bulk(
        [logs], Path("ray-out"), AnnotateOptions(forecasts=fc), engine="ray", workers=2, retries=1
    )
    assert len(result.done) == 3 and not result.failed
    assert _tree(tmp_path / "ray-out") == _tree(tmp_path / "pool") and len(_tree(tmp_path / "pool")) == 3
    again = run_bulk([logs], Path("ray-out"), AnnotateOptions(forecasts=fc), engine="ray", workers=2)
    assert len(again.skipped) == 3 and not again.entries


def _silent_listener() -> socket.socket:
    """A TCP port that accepts connections and never answers (not a Ray cluster)."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    return server


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["closed port", "silent port", "ray client"])
def test_a_wrong_ray_address_fails_fast_and_clearly(tmp_path: Path, kind: str) -> None:
    pytest.importorskip("ray")
    logs, fc = make_fleet(tmp_path, 1, messages=10)
    listener = _silent_listener()
    port = listener.getsockname()[1]
    if kind == "closed port":
        listener.close()
    address = f"ray://127.0.0.1:{port}" if kind == "ray client" else f"127.0.0.1:{port}"
    done = subprocess.run(
        _cli(
            str(logs),
            "--out",
            str(tmp_path / "o"),
            "--forecasts",
            str(fc),
            "--engine",
            "ray",
            "--address",
            address,
        ),
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO), "RAY_ADDRESS": ""},
        capture_output=True,
        text=True,
        timeout=120,
    )
    listener.close()
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert "lanecast annotate: error: " in done.stderr and ("Ray" in done.stderr or "ray" in done.stderr)
    assert address in done.stderr


def _same_size_log(path: Path, letter: str) -> Path:
    """An uncompressed MCAP whose size does not depend on ``letter`` (one message's payload)."""
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.NONE)
        w.start(profile="", library="test-writer")
        schema = w.register_schema("test.Pose", "jsonschema", b'{"type":"object"}')
        channel = w.register_channel("/pose", "json", schema)
        for i in range(40):
            t = i * 100_000_000
            w.add_message(channel, t, json.dumps({"i": i, "pad": letter * 8}).encode(), t, i)
        w.finish()
    return path


def test_changed_input_options_or_force_redo_and_nothing_else(tmp_path: Path) -> None:
    logs, fc = make_fleet(tmp_path, 2, messages=20)
    out = tmp_path / "out"
    a = _same_size_log(logs / "day2" / "log00.mcap", "a")
    first = run_bulk([logs], out, AnnotateOptions(forecasts=fc))
    assert len(first.done) == 2

    # the same size and mtime (as after `cp -p` of another recording): still redone
    st = a.stat()
    b = _same_size_log(tmp_path / "b.mcap", "b")
    assert b.stat().st_size == st.st_size and checksum(b) != checksum(a)
    shutil.copyfile(b, a)
    os.utime(a, ns=(st.st_atime_ns, st.st_mtime_ns))
    second = run_bulk([logs], out, AnnotateOptions(forecasts=fc))
    assert [Path(e["input"]).name for e in second.done] == ["log00.mcap"] and len(second.skipped) == 1
    assert second.redone == {"input changed": 1}
    assert "redone: 1 input changed" in second.summary()

    third = run_bulk([logs], out, AnnotateOptions(forecasts=fc, every_s=0.5))  # other options: all redone
    assert len(third.done) == 2 and third.redone == {"options changed": 2}
    assert {e["options"]["every_s"] for e in third.done} == {0.5}
    assert len(run_bulk([logs], out, AnnotateOptions(forecasts=fc, every_s=0.5)).skipped) == 2

    forced = run_bulk([logs], out, AnnotateOptions(forecasts=fc, every_s=0.5), force=True)
    assert len(forced.done) == 2 and forced.redone == {"forced": 2}


def test_another_model_means_other_options(tmp_path: Path) -> None:
    """The options record the model's checksum: a model with other weights redoes the log."""
    from lanecast.models.checkpoint import resolve
    from lanecast.workflows.bulk.manifest import options_key, stat_signature
    from lanecast.workflows.bulk.runner import model_identity, plan

    shipped = model_identity(None)
    weights, card = resolve(None)
    other = tmp_path / "model"
    other.mkdir()
    shutil.copy(card, other / card.name)
    data = bytearray(weights.read_bytes())
    data[-1] ^= 1
    (other / weights.name).write_bytes(bytes(data))
    retrained = model_identity(other)
    assert retrained["name"] == shipped["name"] and retrained["sha256"] != shipped["sha256"]
    assert model_identity(other) == retrained and model_identity(resolve(None)[1]) == shipped

    log = make_mcap(tmp_path / "drive.mcap", n=10)
    out = tmp_path / "out"
    manifest = Manifest(out)
    (out / "drive.mcap").parent.mkdir()
    (out / "drive.mcap").write_bytes(b"made by lanecast")
    done, _ = plan([log], out, manifest, model=shipped)
    manifest.append(
        {
            "input": str(log.resolve()),
            "output": "drive.mcap",
            "status": "done",
            "options": done[0].options,
            "options_key": options_key(done[0].options),
            "stat": stat_signature(log),
            "sha256": checksum(log),
            "output_sha256": checksum(out / "drive.mcap"),
        }
    )
    assert plan([log], out, manifest, model=shipped) == ([], [log])
    redo, _ = plan([log], out, manifest, model=retrained)
    assert [(t.output, t.reason) for t in redo] == [(out / "drive.mcap", "options changed")]


def test_two_logs_of_one_name_get_two_readable_outputs_and_keep_them(tmp_path: Path) -> None:
    """`annotate a/drive.mcap b/drive.mcap` → OUT/a/drive.mcap and OUT/b/drive.mcap; a later run of
    `other/drive.mcap` into the same OUT never takes a name another log holds."""
    fc = tmp_path / "fc"
    fc.mkdir()
    pq.write_table(forecasts_for("drive", [1, 2, 3], [1, 2]), fc / "drive.parquet")
    logs = []
    for folder, n in (("a", 20), ("b", 21), ("other", 22)):
        (tmp_path / folder).mkdir()
        logs.append(make_mcap(tmp_path / folder / "drive.mcap", n=n))
    out = tmp_path / "out"
    first = run_bulk(logs[:2], out, AnnotateOptions(forecasts=fc))
    assert sorted(e["output"] for e in first.done) == ["a/drive.mcap", "b/drive.mcap"]
    for log, folder in zip(logs[:2], "ab", strict=True):
        assert_all_original_records_equal(log, out / folder / "drive.mcap")

    alone = run_bulk([logs[0]], out, AnnotateOptions(forecasts=fc))  # a/drive.mcap keeps its name
    assert alone.skipped == [logs[0]] and not alone.entries
    other = run_bulk([logs[2]], out, AnnotateOptions(forecasts=fc))  # `drive.mcap` alone would be free,
    assert [e["output"] for e in other.done] == ["drive.mcap"]  # and it is the mirror of `other/`
    before = _tree(out)
    moved = tmp_path / "c"
    moved.mkdir()
    shutil.copy(logs[0], moved / "drive.mcap")  # another input named like one that holds drive.mcap
    again = run_bulk([moved / "drive.mcap"], out, AnnotateOptions(forecasts=fc))
    assert [e["output"] for e in again.done] == ["c/drive.mcap"]
    assert {k: v for k, v in _tree(out).items() if k != "c/drive.mcap"} == before


def test_a_file_lanecast_did_not_write_is_never_overwritten(tmp_path: Path) -> None:
    logs, fc = make_fleet(tmp_path, 2, messages=20)
    out = tmp_path / "out"
    (out / "day2").mkdir(parents=True)
    (out / "day2" / "log01.mcap").write_bytes(b"the user's own file")
    with pytest.raises(InputError, match="not written by lanecast annotate"):
        run_bulk([logs], out, AnnotateOptions(forecasts=fc))
    assert (out / "day2" / "log01.mcap").read_bytes() == b"the user's own file"
    assert not (out / "day2" / "log00.mcap").exists()  # refused before any work
    with pytest.raises(InputError, match="not written by lanecast annotate"):
        run_bulk([logs], out, AnnotateOptions(forecasts=fc), force=True)


def test_each_log_of_one_name_gets_its_own_report_folder(tmp_path: Path) -> None:
    from lanecast.workflows.annotation.log_scores import per_log_names

    logs = [make_mcap(tmp_path / d / "drive.mcap", n=5) for d in ("a", "b") if (tmp_path / d).mkdir() is None]
    assert per_log_names(logs) == {logs[0]: "a/drive", logs[1]: "b/drive"}
    assert per_log_names(logs[:1]) == {logs[0]: "drive"}


def test_a_failed_log_reached_through_a_symlink_is_named_as_given(tmp_path: Path) -> None:
    """The FAILED line names the path the user gave (the link), not the file it points at; the
    manifest keeps the real path (its key for resuming)."""
    real = tmp_path / "real"
    real.mkdir()
    make_mcap(real / "cut.mcap", n=50)
    data = (real / "cut.mcap").read_bytes()
    (real / "cut.mcap").write_bytes(data[: len(data) // 2])
    (tmp_path / "alias.mcap").symlink_to(real / "cut.mcap")  # a linked log
    (tmp_path / "linked").symlink_to(real, target_is_directory=True)  # a log in a linked folder
    for given, out in ((tmp_path / "alias.mcap", tmp_path / "o1"), (tmp_path / "linked", tmp_path / "o2")):
        result = subprocess.run(
            _cli(str(given), "--out", str(out)),
            cwd=REPO,
            env={**os.environ, "PYTHONPATH": str(REPO)},
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert result.returncode == 2, result.stderr
        shown = str(given if given.suffix else given / "cut.mcap")
        said = result.stdout + result.stderr
        failed = [line for line in said.splitlines() if "FAILED" in line]
        assert failed and all(f"FAILED {shown}:" in line for line in failed), said
        assert f"FAILED {real / 'cut.mcap'}" not in said
        assert "Traceback" not in result.stderr
    # the summary of a run that keeps its manifest (one good log beside the bad one)
    make_mcap(real / "good.mcap", n=50)
    fc = tmp_path / "fc"
    fc.mkdir()
    pq.write_table(forecasts_for("good", [1, 2, 3], [1, 2]), fc / "good.parquet")
    pq.write_table(forecasts_for("cut", [1, 2, 3], [1, 2]), fc / "cut.parquet")
    result3 = run_bulk([tmp_path / "linked"], tmp_path / "o3", AnnotateOptions(forecasts=fc))
    assert f"FAILED {tmp_path / 'linked' / 'cut.mcap'}:" in result3.summary()
    manifest = [json.loads(line) for line in (tmp_path / "o3" / "manifest.jsonl").read_text().splitlines()]
    assert {e["input"] for e in manifest} == {str(real / "cut.mcap"), str(real / "good.mcap")}
