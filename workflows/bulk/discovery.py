"""Finding the drive logs of a bulk run and naming their outputs.

:func:`discover` walks the given files and folders for MCAP files, ROS 1 bags and ROS 2 bag
directories (sorted, OUT_DIR excluded); :func:`plan_outputs` names each output by mirroring the
input tree under OUT_DIR (``logs/day2/drive.mcap`` given ``logs/`` → ``OUT_DIR/day2/drive.mcap``),
making a name another input already holds unique with more of the input's folders
(``other/drive.mcap``). The result is one :class:`Task` per log, with absolute paths.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lanecast.io_adapters.files import check_input
from lanecast.io_adapters.formats import registry
from lanecast.workflows.annotation.annotate_log import output_name
from lanecast.workflows.bulk.manifest import absolute


@dataclass(frozen=True)
class Task:
    """One log to annotate: absolute paths, the options that will have made the output, and why."""

    input: Path
    output: Path
    options: dict[str, Any] = field(default_factory=dict)
    reason: str = "new"


def is_ros2_bag(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def discover(paths: Sequence[Path], exclude: Path | None = None) -> list[Path]:
    """The logs named by ``paths``: files as given; directories searched by the registry's walk
    (``registry.walk_logs``: ``*.mcap``, ``*.bag`` and ROS 2 bag directories), skipping ``exclude``
    (OUT_DIR); each log once (the first name it was found under), as named (links not resolved)."""
    found: list[Path] = []
    excluded = os.path.realpath(exclude) if exclude is not None else None
    for p in map(Path, paths):
        check_input(p)
        if p.is_dir() and not is_ros2_bag(p):
            found.extend(registry.walk_logs(p, excluded))
        else:
            found.append(p)
    unique: dict[Path, Path] = {}  # one log named twice (or through a link) is one log
    for p in found:
        unique.setdefault(Path(os.path.realpath(p)), p)
    # the paths as named, not where links lead: outputs mirror the tree the user named (a linked
    # folder, a log linked in from elsewhere)
    return list(unique.values())


def argument_root(path: Path) -> Path:
    """The folder an argument's logs are named relative to: a directory itself, a file's parent."""
    path = absolute(path)
    return path if path.is_dir() and not is_ros2_bag(path) else path.parent


def common_root(paths: Sequence[Path]) -> Path:
    """The deepest folder holding every argument: outputs mirror the input tree below it."""
    return Path(os.path.commonpath([str(argument_root(p)) for p in paths]))


def name_candidates(src: Path, root: Path) -> Iterator[str]:
    """Output names for ``src`` (absolute, under ``root``), most readable first: its path below
    ``root``; then with more and more of its parent folders in front; last, a hash of its path."""
    rel = src.relative_to(root).parent / output_name(src)
    yield rel.as_posix()
    folders = src.parent.parts  # ("/", "data", ..., its folder)
    for k in range(len(rel.parts), len(folders)):
        yield Path(*folders[len(folders) - k :], output_name(src)).as_posix()
    name = output_name(src)
    stem, dot, suffix = name.rpartition(".") if not src.is_dir() else (name, "", "")
    yield (rel.parent / f"{stem}-{hashlib.sha1(str(src).encode()).hexdigest()[:8]}{dot}{suffix}").as_posix()


def plan_outputs(inputs: Sequence[Path], out_dir: Path, *, root: Path | None = None) -> list[Task]:
    """One task per input, outputs mirroring the tree below ``root`` (default: the inputs' common
    folder), each name held by one input only (see ``name_candidates``)."""
    inputs = [absolute(p) for p in inputs]
    root = root if root is not None else common_root(inputs)
    taken: set[str] = set()
    tasks = []
    for src in inputs:
        name = next(n for n in name_candidates(src, root) if n not in taken)
        taken.add(name)
        tasks.append(Task(src, out_dir / name))
    return tasks
