"""pandas deferred in a process: pyarrow works without it, and lanecast's own pandas code still gets
pandas' conversions. Each case runs in a fresh interpreter (the deferral is for a whole process)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from conftest import PEACHTREE, US101

ARROW_WORK = """
import sys
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from lanecast.io_adapters import arrow_pandas
{setup}
codes = pa.array(np.array([2, 0, 2], dtype=np.int32))
names = pa.DictionaryArray.from_arrays(codes, pa.array(["car", "bus", "truck"]))
table = pa.table({{"x": pa.array([1.5, None, 2.5]), "c": names}})
as_numpy = (table.column("x").to_numpy(), names.to_numpy(zero_copy_only=False), np.asarray(pc.sort_indices(codes)))
print("values:", as_numpy[0].tolist(), as_numpy[1].tolist(), as_numpy[2].tolist())
print("pandas:", "pandas" in sys.modules)
{after}
"""


def run_python(code: str) -> list[str]:
    """``code`` run as a lanecast module would (it is the importer pyarrow's imports are seen from)."""
    wrapped = f"exec({code!r}, {{'__name__': 'lanecast.probe'}})"
    done = subprocess.run([sys.executable, "-c", wrapped], capture_output=True, text=True, check=True)
    return done.stdout.splitlines()


def test_deferred_arrow_work_never_imports_pandas_and_gives_the_same_values() -> None:
    deferred = run_python(ARROW_WORK.format(setup="arrow_pandas.defer()", after=""))
    usual = run_python(ARROW_WORK.format(setup="", after=""))
    assert deferred[-1] == "pandas: False"
    assert usual[-1] == "pandas: True"  # what pyarrow does when nobody defers it
    assert deferred[0] == usual[0] == "values: [1.5, nan, 2.5] ['truck', 'car', 'truck'] [1, 0, 2]"


def test_after_allow_pyarrow_converts_pandas_objects_as_pandas_own() -> None:
    after = """
arrow_pandas.allow()
import pandas as pd
kinds = pd.Series(["car", "truck", "car"], dtype="category")
print("dictionary:", pa.types.is_dictionary(pa.array(kinds).type))
print("to_pandas:", table.to_pandas()["c"].tolist())
"""
    lines = run_python(ARROW_WORK.format(setup="arrow_pandas.defer()", after=after))
    assert lines[-2:] == ["dictionary: True", "to_pandas: ['truck', 'car', 'truck']"]


def test_other_libraries_import_pandas_as_usual() -> None:
    after = """
exec("import pandas", {"__name__": "otherlib"})
print("imported:", "pandas" in sys.modules)
print("lanecast's own import:", end=" ")
try:
    exec("import pandas.api", {"__name__": "lanecast.somewhere"})
    print("found")
except ImportError:
    print("refused")
"""
    lines = run_python(ARROW_WORK.format(setup="arrow_pandas.defer()", after=after))
    assert lines[-2:] == ["imported: True", "lanecast's own import: found"]


COMMAND_LINE = """
import sys
from lanecast.workflows.cli import main
sys.argv = ["lanecast", "info", sys.argv[1]]
status = main()
print("pandas:", "pandas" in sys.modules, "status:", status)
"""


def command_line(path: Path) -> subprocess.CompletedProcess[str]:
    """``lanecast info PATH`` as its own process (the command line defers pandas)."""
    return subprocess.run(
        [sys.executable, "-c", COMMAND_LINE, str(path)], capture_output=True, text=True, check=True
    )


def test_a_command_line_process_reads_ngsim_through_pandas_where_it_parses_with_it() -> None:
    txt, csv = command_line(US101), command_line(PEACHTREE)  # the text form parses with pandas
    for done in (txt, csv):
        assert "lane chg" in done.stdout and "total: " in done.stdout, done.stderr[-400:]
    assert txt.stdout.splitlines()[-1] == "pandas: True status: 0"
    assert csv.stdout.splitlines()[-1] == "pandas: False status: 0"


def test_a_bad_ngsim_cell_is_named_in_a_command_line_process(tmp_path: Path) -> None:
    """A text cell sends the CSV export to the checks that locate it, which convert through pandas."""
    lines = PEACHTREE.read_text().splitlines(keepends=True)
    lines[3] = lines[3].replace(",33.96,", ",fast,", 1)
    bad = tmp_path / "peachtree_bad.csv"
    bad.write_text("".join(lines))
    done = command_line(bad)
    assert done.stdout.splitlines()[-1] == "pandas: True status: 2"
    assert "line 4" in done.stderr and "v_Vel" in done.stderr, done.stderr[-400:]
