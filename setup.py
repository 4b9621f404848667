"""The package list and layout of the build (the rest of the metadata is in pyproject.toml).

The repository's top-level folders install as one namespace: ``lanecast.<folder>`` is built from
``<folder>/`` by a ``package_dir`` mapping, not through the links in ``lanecast/``, so a wheel, a
regular install and an editable install are whole where git made no symbolic links
(``core.symlinks=false``). Every package under the folders is found here, so a new one needs no list.
"""

from setuptools import find_packages, setup

FOLDERS = ("io_adapters", "pipeline", "models", "workflows")

setup(
    package_dir={"lanecast": "lanecast", **{f"lanecast.{folder}": folder for folder in FOLDERS}},
    packages=[
        "lanecast",
        *(f"lanecast.{folder}" for folder in FOLDERS),
        *(f"lanecast.{folder}.{sub}" for folder in FOLDERS for sub in find_packages(folder)),
    ],
)
