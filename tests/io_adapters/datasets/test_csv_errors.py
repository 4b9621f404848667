"""The CSV checks the dataset readers share: bad cells, quoted commas, bytes that are no text, huge
cells cut short, lone carriage returns, headers repeated mid-file, zips and other separators under
a CSV name; each named at its file, line and column."""

from __future__ import annotations

import zipfile
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import HEADER, HIGHD, PEACHTREE, US101, _export, _highd_variant, _quoted, _rows, _txt_variant

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats import registry


def test_an_export_zipped_without_compression_under_a_csv_name_is_named_a_zip(tmp_path: Path) -> None:
    """A zip archive that stores its member uncompressed starts with the member's header line: it
    was taken for an NGSIM CSV and refused as "missing column 'vehicle_id'" (a column it has); now
    the format is not recognised and the file is named a zip archive."""
    inner = _export(tmp_path, _rows(1, range(10, 50), 100.0, 4.0)).read_bytes()
    path = tmp_path / "us-101.csv"
    with zipfile.ZipFile(path, "w") as archive:  # ZIP_STORED
        archive.writestr(zipfile.ZipInfo("ngsim-export.csv", (2005, 6, 15, 7, 50, 0)), inner)
    assert inner.splitlines()[0] in path.read_bytes().splitlines()[0]  # the header on the first line
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.offset == 0
    assert "format not recognised: the file is a zip archive" in str(err.value)


@pytest.mark.parametrize(("sep", "named"), [(";", "';'"), ("\t", "tabs")])
def test_an_export_saved_with_semicolons_or_tabs_is_named_as_such(
    tmp_path: Path, sep: str, named: str
) -> None:
    """A spreadsheet in a European locale saves the export with ';' and decimal commas (or as
    tab-separated text): it was "format not recognised" with no hint; now the header's separator
    is named at line 1."""
    lines = [HEADER, *_rows(1, range(10, 50), 100.0, 4.0)]
    path = tmp_path / "export.csv"
    path.write_text("\n".join(line.replace(",", sep) for line in lines).replace(".", ",") + "\n")
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == 1
    assert f"the header is separated by {named}" in str(err.value)


def test_values_beyond_float32_are_refused_at_their_line(tmp_path: Path) -> None:
    path = _highd_variant(tmp_path, 3, "xVelocity", "1e300")
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert (err.value.line, err.value.column) == (3, "xVelocity")
    path = _txt_variant(tmp_path, {(5, 12): "-1e308"})  # v_Acc
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert (err.value.line, err.value.column) == (5, "v_Acc")


def _cell_edit(column: str, value: str) -> Callable[[str], str]:
    """An edit for :func:`_quoted` replacing the (unquoted) ``column`` of a highD tracks or NGSIM CSV line."""

    def edit(text: str) -> str:
        header = (HIGHD / "01_tracks.csv" if column == "x" else PEACHTREE).read_text().split("\n", 1)[0]
        cells = text.split(",")
        cells[header.split(",").index(column)] = value
        return ",".join(cells)

    return edit


@pytest.mark.parametrize(
    ("victim", "column", "value"),
    [
        ("01_tracks.csv", "x", '"952,93"'),  # a decimal comma, quoted by the spreadsheet that wrote it
        ("01_tracks.csv", "x", '"1,952.5"'),  # a thousands separator
        ("peachtree.csv", "Local_Y", '"4,566"'),
    ],
)
def test_a_quoted_comma_is_a_bad_cell_not_a_wrong_field_count(
    tmp_path: Path, victim: str, column: str, value: str
) -> None:
    """A comma inside a quoted value separates no fields: the CSV parser reads the line's fields
    right, so the error names the cell that is no number, not "wrong number of fields"."""
    for kind in ("tracks", "tracksMeta", "recordingMeta"):
        (tmp_path / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
    source = PEACHTREE if victim == "peachtree.csv" else HIGHD / victim
    path = _quoted(source, tmp_path / victim, 3, _cell_edit(column, value))
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert (err.value.path, err.value.line, err.value.column) == (str(path), 3, column)
    assert value.strip('"') in str(err.value) and "number of fields" not in str(err.value)


@pytest.mark.parametrize(
    ("victim", "edit", "match", "line"),
    [
        # a Latin-1 "é" (a file saved by a spreadsheet in the locale's encoding): pyarrow's message
        # named a column number and no line
        ("01_tracksMeta.csv", lambda text: text.replace(",Car,", ",C\xe9r,", 1), "not UTF-8", 2),
        ("01_tracks.csv", lambda text: text.replace(",", "\xe9,", 1), "not UTF-8", 3),
        ("peachtree.csv", lambda text: text.replace(",peachtree", ",peacht\xe9ree"), "not UTF-8", 3),
        # a line longer than the parser's block: "straddling object straddles two block boundaries"
        ("01_tracks.csv", lambda text: text.replace(",", "," + "0" * (1 << 21), 1), "a line of 2,097,", 3),
        (
            "peachtree.csv",
            lambda text: text.replace(",peachtree", ",peachtree" + "x" * (1 << 21)),
            "a line of",
            3,
        ),
    ],
)
def test_bytes_the_csv_parser_cannot_read_as_text_are_named_at_their_line(
    tmp_path: Path, victim: str, edit: Callable[[str], str], match: str, line: int
) -> None:
    for kind in ("tracks", "tracksMeta", "recordingMeta"):
        (tmp_path / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
    source = PEACHTREE if victim == "peachtree.csv" else HIGHD / victim
    path = _quoted(source, tmp_path / victim, line, edit)
    path.write_bytes(path.read_text().encode("latin-1"))
    with pytest.raises(InputError, match=match) as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == line


@pytest.mark.parametrize("form", ["highd", "ngsim-txt", "ngsim-csv"])
def test_a_huge_bad_cell_is_shown_cut_short(tmp_path: Path, form: str) -> None:
    """A damaged file's bad "cell" may be megabytes (a run of NULs after a crash): the one-line error
    quoted all of it."""
    junk = "7" + "z" * 100_000
    if form == "highd":
        path = _highd_variant(tmp_path, 3, "x", junk)
    elif form == "ngsim-txt":
        path = _txt_variant(tmp_path, {(3, 5): junk})
    else:
        path = _quoted(PEACHTREE, tmp_path / "peachtree.csv", 3, _cell_edit("Local_Y", junk))
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert err.value.line == 3 and "'7zzz" in str(err.value) and "100,001 characters" in str(err.value)
    assert len(str(err.value)) < 400


@pytest.mark.parametrize("form", ["highd", "ngsim-txt", "ngsim-csv"])
def test_files_with_carriage_returns_alone_as_line_ends_are_read(tmp_path: Path, form: str) -> None:
    """Line ends of a lone CR (old Mac editors and exports): an NGSIM .txt was "format not
    recognised" and a highD recording had a header "line" of the whole file ("no column ...");
    the parsers read such line ends, and the header detection now does too."""
    if form == "highd":
        sources = [HIGHD / f"01_{kind}.csv" for kind in ("tracks", "tracksMeta", "recordingMeta")]
    else:
        sources = [US101 if form == "ngsim-txt" else PEACHTREE]
    for source in sources:
        lines = source.read_bytes().split(b"\n")[:300]
        (tmp_path / source.name).write_bytes(b"\r".join(line.rstrip(b"\r") for line in lines) + b"\r")
        (tmp_path / "lf").mkdir(exist_ok=True)
        (tmp_path / "lf" / source.name).write_bytes(b"\n".join(lines) + b"\n")
    got = registry.read_any([tmp_path / sources[0].name])
    want = registry.read_any([tmp_path / "lf" / sources[0].name])
    assert got.num_rows > 0 and got.select(got.column_names[1:]).equals(want.select(want.column_names[1:]))
    if form == "ngsim-txt":  # a bad cell in such a file is named at its line
        path = tmp_path / sources[0].name
        lines = path.read_bytes().split(b"\r")
        lines[4] = lines[4].replace(lines[4].split()[5], b"x", 1)
        path.write_bytes(b"\r".join(lines))
        with pytest.raises(InputError) as err:
            registry.read_any([path])
        assert err.value.line == 5 and err.value.column == "Local_Y"


@pytest.mark.parametrize("form", ["highd", "highd-streamed", "ngsim-txt", "ngsim-csv", "ngsim-csv-streamed"])
def test_a_header_repeated_mid_file_is_named_as_such(tmp_path: Path, form: str) -> None:
    """Two files joined into one (``cat a.csv b.csv``) put the header line amid the rows: it was
    refused as "cell 'frame' is not an integer" ('Vehicle_ID' is not a finite number), which sends
    a user looking for a bad value; now it says the header is there again, at its line."""
    from lanecast.io_adapters.datasets.highd import reader as highd
    from lanecast.io_adapters.datasets.highd import stream as highd_stream
    from lanecast.io_adapters.datasets.ngsim.reader import TXT_COLUMNS
    from lanecast.io_adapters.formats import streaming

    if form.startswith("highd"):
        source = HIGHD / "01_tracks.csv"
        for kind in ("tracksMeta", "recordingMeta"):
            (tmp_path / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
    else:
        source = US101 if form == "ngsim-txt" else PEACHTREE
    lines = source.read_text().splitlines()[:50]
    header = "  ".join(TXT_COLUMNS) if form == "ngsim-txt" else lines[0]
    path = tmp_path / source.name
    path.write_text("\n".join([*lines[:4], header, *lines[4:]]) + "\n")
    with pytest.raises(InputError) as err:
        if form == "highd-streamed":
            highd_stream.split_tracks(highd.recordings([path])[0], tmp_path, block_bytes=1 << 10)
        elif form == "ngsim-csv-streamed":
            streaming.plan([path], spill_dir=tmp_path / "spill", stream_bytes=0)
        else:
            registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == 5, str(err.value)
    assert ("column names" if form == "ngsim-txt" else "header line again") in str(err.value)
