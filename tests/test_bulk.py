"""Bulk annotation: manifest, resume after failure and after SIGKILL, worker processes, Ray.

The logs are real MCAP files (tests/test_annotate.make_mcap) with precomputed forecasts tables
(``--forecasts DIR``), so that these tests exercise the runner and not the model.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from conftest import assert_all_original_records_equal, forecasts_for, make_mcap
from mcap.reader import make_reader

from lanecast.workflows.annotate_log import AnnotateOptions
from lanecast.workflows.bulk import Manifest, checksum, clean_temporaries, discover, plan_outputs, run_bulk
from lanecast.workflows.log_report import annotated_logs

REPO = Path(__file__).resolve().parents[1]


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
    names = [t.output.name for t in plan_outputs(found, out)]
    assert names[:2] == ["log01.mcap", "log02.mcap"]
    assert names[2] != names[3] and names[2].startswith("log00-") and names[3].endswith(".mcap")


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
    done = next(e for e in entries if e["input"].endswith("log00.mcap"))
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
    assert len(first.done) == 2 and (tmp_path / "a" / "out" / "log00.mcap").is_file()
    assert {e["output"] for e in Manifest(tmp_path / "a" / "out").entries()} == {"log00.mcap", "log01.mcap"}

    monkeypatch.chdir(tmp_path / "a" / "b")
    again = run_bulk([Path("../../logs")], Path("../out"), AnnotateOptions(forecasts=fc))
    assert len(again.skipped) == 2 and not again.entries
    assert len(Manifest(tmp_path / "a" / "out").entries()) == 2  # no second entry per log

    monkeypatch.chdir(tmp_path)
    found = annotated_logs([Path("a/out")])
    assert found == [Path("a/out/log00.mcap"), Path("a/out/log01.mcap")] and all(p.is_file() for p in found)


def test_manifest_survives_a_line_cut_short_and_temporaries_are_cleaned(tmp_path: Path) -> None:
    m = Manifest(tmp_path)
    m.append({"input": "/a", "status": "done"})
    with open(m.path, "a") as f:
        f.write('{"input": "/b", "sta')  # a kill in the middle of a write
    m.append({"input": "/c", "status": "failed"})
    assert [e["input"] for e in m.entries()] == ["/a", "/c"]
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
    assert sorted(p.name for p in out.iterdir()) == [
        ".lanecast-annotate.lock",
        "log00.mcap",
        "log01.mcap",
        "log02.mcap",
        "log03.mcap",
        "manifest.jsonl",
    ]
    for i in range(4):
        sub = "day2/" if i >= 2 else ""
        assert_all_original_records_equal(logs / f"{sub}log{i:02d}.mcap", out / f"log{i:02d}.mcap")


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "lanecast.workflows.cli", "annotate", *args]


# The real command, paused inside the copy of its third log until it is killed: the kill lands
# mid-log at a known point (two logs done) instead of racing a poll against the run.
_PAUSE_IN_THIRD_LOG = """
import sys, time
from pathlib import Path
from lanecast.io_adapters.annotations import mcap_copy
from lanecast.workflows.cli import main
ready, copy_mcap, calls = Path(sys.argv[1]), mcap_copy.copy_mcap, []
def pausing_copy(src, out, **kwargs):
    calls.append(src)
    if len(calls) == 3:
        out.write(b"half a log")
        ready.write_text(str(src))
        time.sleep(600)
    return copy_mcap(src, out, **kwargs)
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
    killed_with = len(Manifest(out).entries())
    assert 2 <= killed_with < n

    rerun = subprocess.run(args, cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert rerun.returncode == 0, rerun.stderr
    assert f"{killed_with} already done" in rerun.stdout
    entries = Manifest(out).entries()
    assert all(e["status"] == "done" for e in entries)
    per_input = [Path(e["input"]).name for e in entries]
    assert sorted(per_input) == sorted(f"log{i:02d}.mcap" for i in range(n))  # each exactly once
    assert sorted(p.name for p in out.glob("*.mcap")) == sorted(f"log{i:02d}.mcap" for i in range(n))
    assert not [p for p in out.iterdir() if ".tmp-" in p.name]
    for i in range(n):
        assert forecast_count(out / f"log{i:02d}.mcap") == 3


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


@pytest.mark.slow
def test_ray_engine_annotates_logs_on_a_local_ray(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    logs, fc = make_fleet(tmp_path, 3, messages=30)
    out = tmp_path / "out"
    result = run_bulk([logs], out, AnnotateOptions(forecasts=fc), engine="ray", workers=2, retries=1)
    assert len(result.done) == 3 and not result.failed
    for i in range(3):
        sub = "day2/" if i >= 1 else ""
        assert_all_original_records_equal(logs / f"{sub}log{i:02d}.mcap", out / f"log{i:02d}.mcap")
    again = run_bulk([logs], out, AnnotateOptions(forecasts=fc), engine="ray", workers=2)
    assert len(again.skipped) == 3 and not again.entries
    assert json.loads((out / "manifest.jsonl").read_text().splitlines()[0])["status"] == "done"
