"""Check that the package is whole where it is built and where it is type-checked (a report, not a test).

1. The wheel: built from the source tree (``pip wheel``), it must hold every file of the package's
   folders (modules, weights, message definitions) under ``lanecast/`` and nothing else but its
   ``.dist-info``. setup.py maps each folder to ``lanecast.<folder>``, so this holds with or
   without the links in ``lanecast/``; a package setup.py failed to list shows up here.
2. The links: ``lanecast/<folder>`` must lead to ``<folder>``. The build does not need them, but
   mypy and tools that read the tree do; where git made none (``core.symlinks=false``), mypy would
   check two files and pass, so this says so instead.

    python .ci/check_package.py [--root .] [--no-build-isolation]   # exit status 1 when one fails
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from check_layout import PACKAGES


def source_files(root: Path) -> set[str]:
    """The files a wheel must hold, as paths inside it: lanecast/<folder>/... and lanecast/*.py."""
    out = {f"lanecast/{p.name}" for p in (root / "lanecast").glob("*.py")}
    for folder in PACKAGES:
        for path in (root / folder).rglob("*"):
            if path.is_file() and "__pycache__" not in path.parts and path.suffix != ".pyc":
                out.add(f"lanecast/{path.relative_to(root).as_posix()}")
    return out


def wheel_files(root: Path, isolation: bool) -> set[str]:
    """The files of a wheel built from ``root`` (its .dist-info left out); setuptools' ``build/``
    is removed again unless it was there before."""
    made_build = not (root / "build").exists()
    with tempfile.TemporaryDirectory() as out:
        command = [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--wheel-dir", out]
        subprocess.run([*command, *([] if isolation else ["--no-build-isolation"]), str(root)], check=True)
        if made_build:
            shutil.rmtree(root / "build", ignore_errors=True)
        (wheel,) = Path(out).glob("lanecast-*.whl")
        with zipfile.ZipFile(wheel) as z:
            return {n for n in z.namelist() if not n.split("/", 1)[0].endswith(".dist-info")}


def broken_links(root: Path) -> list[str]:
    """lanecast/<folder> entries that do not lead to <folder>."""
    return [
        f"lanecast/{folder}"
        for folder in PACKAGES
        if not (root / "lanecast" / folder).is_dir()
        or (root / "lanecast" / folder).resolve() != (root / folder).resolve()
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parent.parent)
    ap.add_argument("--no-build-isolation", action="store_true", help="build with the setuptools installed")
    args = ap.parse_args()
    root = args.root.resolve()
    broken = 0

    expected = source_files(root)
    built = wheel_files(root, isolation=not args.no_build_isolation)
    missing, extra = sorted(expected - built), sorted(built - expected)
    print(f"1. wheel: {len(built)} files, {len(expected)} expected from the source folders")
    for name in missing:
        print(f"   MISSING {name}")
    for name in extra:
        print(f"   NOT FROM THE SOURCE FOLDERS {name}")
    broken += len(missing) + len(extra)

    links = broken_links(root)
    print(f"\n2. links in lanecast/: {len(PACKAGES) - len(links)} of {len(PACKAGES)} lead to their folder")
    for name in links:
        print(f"   NOT A LINK {name} (git made no symbolic links? mypy would not see the folder)")
    broken += len(links)

    print(f"\n{'OK' if not broken else f'{broken} problem(s)'}")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
