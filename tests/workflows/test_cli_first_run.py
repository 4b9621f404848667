"""A new user's first run: `lanecast` alone, --help on any terminal, reports in any locale, the
demo's --out, the --help examples in order, and errors that say what an example needs."""

from __future__ import annotations

import argparse
import errno
import io
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, make_track_table, synthetic_windows

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.windows_store.dataset import save_windows
from lanecast.workflows import cli, demo

SUFFIXES = (".parquet", ".mcap", ".bag", ".csv", ".txt", ".json", ".safetensors")


def lanecast(*args: str, env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """`python -m lanecast ARGS` in a new process with ``env`` on top of this one's; output as bytes
    decoded as UTF-8 (what a UTF-8 terminal would show)."""
    done = subprocess.run(
        [sys.executable, "-m", "lanecast", *args],
        env={**os.environ, "PYTHONPATH": str(REPO), **env},
        cwd=cwd,
        capture_output=True,
        timeout=300,
    )
    return subprocess.CompletedProcess(
        done.args, done.returncode, done.stdout.decode("utf-8"), done.stderr.decode("utf-8")
    )


def test_lanecast_alone_shows_the_commands(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([]) == 0
    out = capsys.readouterr().out
    assert "Start with: lanecast demo" in out
    assert all(f"    {command} " in out for command in cli.COMMANDS)


@pytest.mark.parametrize("encoding", ["ascii", "latin-1"])
def test_help_on_a_terminal_that_is_not_utf8(encoding: str, tmp_path: Path) -> None:
    """`lanecast demo --help` printed a traceback at its first arrow; now arrows are spelled."""
    done = lanecast("demo", "--help", env={"PYTHONIOENCODING": encoding}, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "SUMO traffic -> track table -> MCAP drive log" in done.stdout
    assert done.stderr == ""


def test_unencodable_characters_are_spelled_and_file_name_bytes_kept() -> None:
    text = "a → b … 3 × 4 ≥ 2 ✓ \udce9t\udce9.mcap"
    assert text.encode("ascii", errors="lanecast-ascii") == b"a -> b ... 3 x 4 >= 2 ? \xe9t\xe9.mcap"


@pytest.mark.slow
def test_reports_are_utf8_in_an_ascii_locale(tmp_path: Path) -> None:
    """In a C locale without UTF-8 mode, writing report.md (an en dash, ±) raised UnicodeEncodeError."""
    save_windows(synthetic_windows(300, seed=2), tmp_path / "windows")
    env = {"PYTHONUTF8": "0", "LC_ALL": "C", "LANG": "C"}
    done = lanecast("evaluate", "windows", "--out", "report", env=env, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "–" in (tmp_path / "report" / "report.md").read_text(encoding="utf-8")
    assert "<meta charset='utf-8'>" in (tmp_path / "report" / "report.html").read_text(encoding="utf-8")


def test_matplotlib_without_a_writable_home_says_nothing(tmp_path: Path) -> None:
    """HOME unset or read-only: matplotlib's two lines about a temporary config directory are not shown."""
    (tmp_path / "home").write_text("a file, not a directory: no config directory can be made in it")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MPL", "XDG_"))}
    done = subprocess.run(
        [sys.executable, "-c", "from lanecast.models.reports.plots import pyplot; pyplot().figure()"],
        env={**env, "HOME": str(tmp_path / "home"), "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""


# ------------------------------------------------------------------------------------ demo --out


def test_demo_refuses_an_out_holding_what_it_did_not_write(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`lanecast demo --out .` beside one's own tracks.parquet overwrote it; now it is refused before
    anything is simulated."""
    mine = tmp_path / "tracks.parquet"
    mine.write_bytes(b"my own table")
    assert cli.main(["demo", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"{mine}: exists and was not written by `lanecast demo`" in err
    assert mine.read_bytes() == b"my own table"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tracks.parquet"]


def test_demo_claims_a_new_empty_or_previous_demo_directory(tmp_path: Path) -> None:
    demo.claim(tmp_path / "new" / "demo")  # created, parents too
    assert (tmp_path / "new" / "demo" / demo.MARK).is_file()
    (tmp_path / "empty").mkdir()
    demo.claim(tmp_path / "empty")
    (tmp_path / "empty" / "tracks.parquet").write_bytes(b"the demo's own")
    demo.claim(tmp_path / "empty")  # a rerun: its mark says the outputs are the demo's
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("unrelated")
    demo.claim(tmp_path / "other")  # nothing the demo writes is there: it writes beside it


def test_demo_reruns_in_a_directory_an_earlier_version_made(tmp_path: Path) -> None:
    """A demo folder from before the mark (no .lanecast-demo) is recognised by its annotation
    manifest, whose input is the demo's log: the rerun after an upgrade is not refused."""
    from lanecast.workflows.bulk.manifest import Manifest

    (tmp_path / "tracks.parquet").write_bytes(b"the old demo's")
    Manifest(tmp_path / "annotated").append(
        {"input": str(tmp_path / "logs" / "highway.mcap"), "status": "done"}
    )
    demo.claim(tmp_path)
    assert (tmp_path / demo.MARK).is_file()


def test_demo_checks_its_options_before_making_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`lanecast demo --minutes 0` said '<input>: invalid simulation parameter …' after making --out."""
    assert cli.main(["demo", "--out", str(tmp_path / "d"), "--minutes", "0"]) == 2
    assert capsys.readouterr().err == (
        "lanecast demo: error: --minutes 0.0: invalid (expected a number of minutes above 0, at most 120)\n"
    )
    assert not (tmp_path / "d").exists()


def test_demo_refuses_a_file_as_out(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "f").write_text("x")
    assert cli.main(["demo", "--out", str(tmp_path / "f")]) == 2
    assert "exists and is not a directory" in capsys.readouterr().err


# ------------------------------------------------------------------------------- --help examples


def help_examples() -> list[tuple[str, bool]]:
    """Every --help example in command order, with whether it needs what a new user has not got
    (the examples under a 'with a dataset downloaded:' or 'with a Ray cluster:' line)."""
    parser = cli.build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices  # type: ignore[union-attr]
    examples = []
    for name in cli.COMMANDS:
        epilog = commands[name].epilog or ""  # type: ignore[index]
        download = False
        for line in epilog.splitlines():
            if line.startswith("with "):
                download = True
            elif line.startswith("  lanecast "):
                examples.append((line.split("#", 1)[0].strip(), download))
    return examples


def test_help_examples_run_in_order_on_what_earlier_ones_made() -> None:
    """In a new directory, in order, every relative input an example names was made by an earlier
    example (the first is the demo); only the examples under 'with a dataset …' or 'with a Ray
    cluster' need more."""
    made = {"lanecast-demo/" + name for name in demo.OUTPUTS}
    downloads = []
    for line, download in help_examples():
        words = line.split()
        outputs = {words[i + 1].rstrip("/") for i, w in enumerate(words) if w == "--out"}
        if words[1] == "export":  # writes beside the model it is given
            outputs.add(words[2])
        values = {words[i + 1] for i, w in enumerate(words) if w in ("--model", "--init")}
        inputs = [
            w
            for w in words[2:]
            if not w.startswith("-") and "://" not in w and ("/" in w or Path(w).suffix in SUFFIXES)
        ]
        needed = {p.rstrip("/") for p in [*inputs, *values] if p != "default" and not p.startswith("/")}
        needed -= outputs
        missing = [
            p
            for p in needed
            if not any(p == m or f"{m}/".startswith(f"{p}/") or p.startswith(f"{m}/") for m in made)
        ]
        if download:
            downloads.append(line)
            assert missing or "--engine ray" in line, f"{line}: under 'with …' but needs nothing new"
        else:
            assert not missing, f"{line}: {missing} is made by no earlier example"
        made |= outputs
    assert downloads == [
        "lanecast convert ngsim/ --out us101.parquet",
        "lanecast convert ngsim/*.txt --to csp --out csp/",
        "lanecast annotate logs/ --out /shared/annotated --engine ray --address ray://head:10001",
    ]


def test_a_missing_input_says_what_the_argument_takes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["convert", str(tmp_path / "ngsim/"), "--out", str(tmp_path / "us101.parquet")]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"lanecast convert: error: {tmp_path / 'ngsim'}: no such file or directory "
        "(expected INPUT: highD, NGSIM, MCAP, ROS 1/2 bag or track-table files or directories)\n"
    )


def test_ray_install_advice_is_for_this_environment() -> None:
    """`pip install 'lanecast[ray]'` would fetch another lanecast than a clone's."""
    from lanecast.workflows.bulk import ray_backend as ray_engine

    extra = re.search(r'^ray = \["([^"]+)"\]', (REPO / "pyproject.toml").read_text(), re.M)
    assert extra is not None and extra.group(1) == ray_engine.RAY_REQUIREMENT
    assert ray_engine.install_ray() == f"{sys.executable} -m pip install '{ray_engine.RAY_REQUIREMENT}'"


def test_explain_says_when_a_track_of_a_table_has_windows(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A time off the log's clock (the --help example's time on another log) names the track's span."""
    n = 100  # 10 s at 10 Hz
    table = make_track_table(
        {"track_id": np.repeat([1, 2], n), "frame": np.tile(np.arange(n), 2),
         "x": np.concatenate([np.arange(n) * 3.0, np.arange(n) * 3.0 + 30]), "y": np.zeros(2 * n),
         "lane_id": np.ones(2 * n, dtype=np.int32)},
    )  # fmt: skip
    path = track_table.write_parquet(table, tmp_path / "t.parquet")
    args = ["explain", str(path), "--out", str(tmp_path / "e")]
    assert cli.main([*args, "--track", "1", "--time", "1700000123.4"]) == 2
    assert (
        "track 1 has no window at t0 = 1700000123.4 s: it is in INPUT from 0.0 to 9.9 s "
        "(expected a time after 3 s of gap-free history: 2.9 … 9.9 s)"
    ) in capsys.readouterr().err
    assert cli.main([*args, "--track", "7", "--time", "5"]) == 2
    assert "no track 7 (expected a track id of INPUT (1 … 2;" in capsys.readouterr().err
    assert not (tmp_path / "e").exists()


@pytest.mark.parametrize(
    "command",
    [
        ["simulate", "--minutes", "5", "--seed", "1"],
        ["windows", "any.parquet"],
        ["train", "any-windows"],
        ["ablate", "any-windows", "--quick"],
        ["demo"],
    ],
)
def test_an_unwritable_out_is_refused_before_the_work(
    command: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """In a read-only directory, simulate, train and ablate failed only after simulating or training
    (simulate naming a temporary directory); now --out is checked first."""
    (tmp_path / "file").write_text("a file where a directory would have to be")
    out = tmp_path / "file" / "out"
    assert cli.main([*command, "--out", str(out)]) == 2
    assert capsys.readouterr().err.endswith(f"error: {out}: cannot write here: Not a directory\n")


def test_demo_in_a_directory_it_cannot_write_says_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The README's command in a read-only directory: one line naming the directory, no traceback.
    (os.access stands in for a read-only mount, which root's permission bits cannot give.)"""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(os, "access", lambda *args, **kwargs: False)
    assert cli.main(["demo"]) == 2
    assert capsys.readouterr().err == (
        "lanecast demo: error: lanecast-demo: the directory . is not writable "
        "(expected an --out in a directory you can write to)\n"
    )
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------- locales, disks, arguments


def test_stderr_in_an_ascii_locale_spells_what_it_cannot_encode(monkeypatch: pytest.MonkeyPatch) -> None:
    """stderr's own error handler (backslashreplace) printed an error's ellipsis as \\u2026 and a file
    name's undecodable bytes as \\udce9 in a C locale; now they are spelled, and the bytes kept."""
    stream = io.TextIOWrapper(io.BytesIO(), encoding="ascii", errors="backslashreplace")
    monkeypatch.setattr(sys, "stderr", stream)
    cli.printable_everywhere()
    print("times 2.9 … 9.9 s in caf\udce9.mcap", file=sys.stderr)
    stream.flush()
    assert stream.buffer.getvalue() == b"times 2.9 ... 9.9 s in caf\xe9.mcap\n"  # type: ignore[attr-defined]


def test_a_non_ascii_name_in_an_ascii_locale_is_refused_up_front(tmp_path: Path) -> None:
    """In a C locale without UTF-8 mode, the demo in a folder named 'été' simulated, then ended in
    pyarrow's traceback ('UnicodeEncodeError: … surrogates not allowed'; in ISO-8859-1, 'No such
    file or directory' for a folder that exists): pyarrow takes names in UTF-8 only. Now one line,
    before any work, names the path."""
    table = make_track_table(
        {"track_id": [1, 1], "frame": [0, 1], "x": [0.0, 3.0], "y": [0.0, 0.0], "lane_id": [1, 1]}
    )
    track_table.write_parquet(table, tmp_path / "t.parquet")
    (tmp_path / "été").mkdir()
    env = {"LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONCOERCECLOCALE": "0", "PYTHONIOENCODING": ""}
    done = subprocess.run(
        [sys.executable, "-m", "lanecast", "convert", "t.parquet", "--out", "été/t.parquet"],
        env={**os.environ, "PYTHONPATH": str(REPO), **env},
        cwd=tmp_path,
        capture_output=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    expected = (
        "lanecast convert: error: été/t.parquet: a name beyond ASCII, which this locale encodes in "
        "ascii but pyarrow in UTF-8 (expected a UTF-8 locale: run with LC_ALL=C.UTF-8 or PYTHONUTF8=1)\n"
    )
    assert done.stderr == expected.encode()
    assert list((tmp_path / "été").iterdir()) == []


def test_a_name_pyarrow_cannot_encode_is_named(tmp_path: Path) -> None:
    """A file name whose bytes are not UTF-8 (in a UTF-8 locale, a surrogate escape) ended in
    pyarrow's UnicodeEncodeError traceback; the error names its folder and says to rename it."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    folder = tmp_path / "caf\udce9"
    with pytest.raises(UnicodeEncodeError) as refused:
        pq.write_table(pa.table({"x": [1.0]}), str(folder / "t.parquet"))
    assert cli.unencodable_path(refused.value) == (
        f"{folder}: a name not in this locale's encoding (utf-8), which pyarrow needs "
        "(expected a file or folder name in UTF-8: rename it)"
    )
    assert not folder.exists()


def test_a_full_disk_names_the_output(tmp_path: Path) -> None:
    """A write onto a full disk raises OSError 28 without a file name: `lanecast demo --out` on a
    full disk said 'error: No space left on device' (convert: pyarrow's 'Error writing bytes to
    file. Detail: [errno 28] …'), naming no path; now it names --out."""
    # as pyarrow raises it, and as a flush of Python's own file does (never written here: pyarrow
    # deletes the file a failed write was to, /dev/full too)
    arrow = OSError(errno.ENOSPC, "Error writing bytes to file. Detail: [errno 28] No space left on device")
    flush = OSError(errno.ENOSPC, "No space left on device")
    args = argparse.Namespace(out=Path("lanecast-demo"))
    for error in (arrow, flush):
        assert cli.environment_error(error, args) == (
            "lanecast-demo: No space left on device (expected free space on its disk for --out, or another --out)"
        )
    assert cli.environment_error(arrow, argparse.Namespace()) == arrow.strerror  # no --out: as raised
    missing = OSError(errno.ENOENT, "No such file or directory", str(tmp_path / "gone"))
    assert cli.environment_error(missing, args) == f"{tmp_path / 'gone'}: No such file or directory"


def one_track_table(path: Path) -> None:
    """A track table of one car driving 50 s at 10 Hz, written to ``path``."""
    table = make_track_table(
        {"track_id": np.ones(500, int), "frame": np.arange(500), "x": np.arange(500.0),
         "y": np.zeros(500), "lane_id": np.ones(500, int)}
    )  # fmt: skip
    track_table.write_parquet(table, path)


def run_with_file_size_limit(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """``lanecast ARGS`` in ``cwd`` where no file may grow past 4 KiB (``ulimit -f``: EFBIG, as a
    full disk gives ENOSPC)."""
    import resource

    return subprocess.run(
        [sys.executable, "-m", "lanecast", *args],
        env={**os.environ, "PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1"},
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (4096, resource.RLIM_INFINITY)),
    )


def test_a_file_size_limit_names_the_output(tmp_path: Path) -> None:
    """A write the system refuses (here: `ulimit -f`, EFBIG; a full disk alike) named no path."""
    one_track_table(tmp_path / "t.parquet")
    done = run_with_file_size_limit(["convert", "t.parquet", "--out", "big.parquet"], tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines()[-1] == (
        "lanecast convert: error: big.parquet: File too large "
        "(expected a file size the system allows (ulimit -f) for --out, or another --out)"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.parquet"]


def test_an_unknown_option_is_refused_with_the_commands_usage(capsys: pytest.CaptureFixture[str]) -> None:
    """`lanecast demo --bogus` showed lanecast's top-level usage and 'lanecast: error:'."""
    with pytest.raises(SystemExit) as done:
        cli.main(["demo", "--bogus", "1"])
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: lanecast demo [-h] [--out OUT]")
    assert err.endswith("\nlanecast demo: error: unrecognized arguments: --bogus 1\n")


def test_a_file_size_limit_in_a_bulk_annotate_names_the_output(tmp_path: Path) -> None:
    """annotate on a full disk said 'OSError: [Errno 28] No space left on device', naming no path."""
    one_track_table(tmp_path / "t.parquet")
    assert cli.main(["convert", str(tmp_path / "t.parquet"), "--out", str(tmp_path / "log.mcap")]) == 0
    done = run_with_file_size_limit(["annotate", "log.mcap", "--out", "out"], tmp_path)
    assert done.returncode == 2, done.stderr
    named = f"{tmp_path / 'out' / 'log.mcap'}: File too large"
    assert done.stderr.splitlines()[-1] == f"lanecast annotate: error: {named}"
    assert f"FAILED {tmp_path / 'log.mcap'}: {named}" in done.stdout
    assert "Traceback" not in done.stderr + done.stdout and "OSError" not in done.stderr + done.stdout
    assert not (tmp_path / "out" / "log.mcap").exists()
