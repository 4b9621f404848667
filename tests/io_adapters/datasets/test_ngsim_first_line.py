"""A bad cell on the first line of an NGSIM .txt is named by line and column, as on any other line."""

from __future__ import annotations

from pathlib import Path

import pytest

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats import registry

FIXTURE = Path(__file__).resolve().parents[2] / "data" / "ngsim" / "us-101" / "trajectories-fixture.txt"


@pytest.mark.parametrize("line", [1, 2])
def test_a_bad_cell_is_named_on_the_first_line_as_on_the_second(tmp_path: Path, line: int) -> None:
    rows = FIXTURE.read_text().splitlines()
    cells = rows[line - 1].split()
    cells[5] = "abc"  # Local_Y
    rows[line - 1] = "  ".join(cells)
    bad = tmp_path / "trajectories-0750am-0805am.txt"
    bad.write_text("\n".join(rows) + "\n")
    with pytest.raises(InputError) as err:
        registry.read_any([bad])
    assert "format not recognised" not in str(err.value)
    assert err.value.line == line and "abc" in str(err.value), str(err.value)


def test_a_text_of_eighteen_words_is_still_not_ngsim(tmp_path: Path) -> None:
    prose = tmp_path / "notes.txt"
    prose.write_text(" ".join(["word"] * 18) + "\n")
    with pytest.raises(InputError, match="format not recognised"):
        registry.read_any([prose])
