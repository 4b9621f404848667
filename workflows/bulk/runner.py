"""Bulk annotation: many logs, a manifest, resume, local worker processes or a Ray cluster.

``OUT_DIR/manifest.jsonl`` (``lanecast.workflows.bulk.manifest``) records, for every log, the output
name it claimed, the options and model that made it and the input's checksum. A rerun:

- skips a log whose latest entry is ``done`` with the same options and an unchanged input whose
  output exists; redoes everything else (failed, never finished, changed input, other options or
  model), and everything with ``force``;
- names outputs by mirroring the input tree under OUT_DIR (``logs/day2/drive.mcap`` given ``logs/``
  → ``OUT_DIR/day2/drive.mcap``); a log keeps the name the manifest gave it; a name another input
  already holds is made unique with more of the input's folders (``other/drive.mcap``);
- never overwrites a file in OUT_DIR that the manifest does not name: the run is refused instead;
- writes outputs only complete (``atomic_path``); leftover ``.*.tmp-*`` entries of a killed run are
  removed when the next run starts (an exclusive lock on OUT_DIR keeps two runs apart).

Backends (``engine=``, the value of ``--engine``): ``local`` runs the per-log task in-process (1 worker) or in a ``ProcessPoolExecutor``;
``ray`` submits the same task (``num_cpus=1``, retried when its worker dies) to a cluster
(``lanecast.workflows.bulk.ray_backend``). Every path a worker gets is absolute.

Finding and naming the logs is :mod:`lanecast.workflows.bulk.discovery`, running the per-log task
:mod:`lanecast.workflows.bulk.tasks`; this module plans a run against the manifest, keeps OUT_DIR
safe (lock, leftovers, foreign files) and records what the backends return.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import shutil
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lanecast
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import checksum
from lanecast.io_adapters.progress import bar
from lanecast.models.card import provenance, provenance_line, resolve
from lanecast.workflows.annotation.annotate_log import (
    AnnotateOptions,
    precomputed_forecasts_path,
)
from lanecast.workflows.bulk import ray_backend
from lanecast.workflows.bulk.discovery import Task, common_root, discover, name_candidates
from lanecast.workflows.bulk.manifest import (
    MANIFEST,
    Manifest,
    absolute,
    not_ours,
    open_regular,
    options_key,
    relative_to_manifest,
    stat_signature,
)
from lanecast.workflows.bulk.tasks import run_inline, run_pool, run_ray

LOCK = ".lanecast-annotate.lock"


@dataclass
class BulkResult:
    """What a bulk run did: entries written this run and the logs skipped as already done."""

    entries: list[dict[str, Any]] = field(default_factory=list)
    skipped: list[Path] = field(default_factory=list)
    out_dir: Path = Path()
    redone: dict[str, int] = field(default_factory=dict)  # reason → count, for the logs not new
    # entry index → the log's path as the user named it (a symbolic link keeps its own name; the
    # manifest's "input" is the real path, its key for resuming)
    given: dict[int, str] = field(default_factory=dict)
    # which model made the forecasts (models.card.provenance_line); None for precomputed forecasts
    model_line: str | None = None
    # --out as the user named it (out_dir is made absolute for the workers)
    out_as_given: Path | None = None

    @property
    def done(self) -> list[dict[str, Any]]:
        return [e for e in self.entries if e["status"] == "done"]

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [e for e in self.entries if e["status"] == "failed"]

    def summary(self) -> str:
        why = ", ".join(f"{n} {reason}" for reason, n in sorted(self.redone.items()))
        shown = self.out_as_given or self.out_dir
        lines = [
            f"annotated {len(self.done)} log(s), {len(self.failed)} failed, {len(self.skipped)} already done"
            + (f" (redone: {why})" if why else "")
            + (
                f" -> {shown} (manifest: {shown / MANIFEST})"
                if (self.out_dir / MANIFEST).is_file()
                else f"; nothing written to {shown}"
            )
        ]
        if self.model_line is not None and self.done:
            lines.append(f"  {self.model_line}")
        lines += [
            f"  FAILED {self.given.get(i, e['input'])}: {e['error']}"
            for i, e in enumerate(self.entries)
            if e["status"] == "failed"
        ]
        counted = [
            e["counts"] for e in self.done if (e.get("counts") or {}).get("out_of_distribution") is not None
        ]
        if counted:
            flagged = sum(int(c["out_of_distribution"]) for c in counted)
            total = sum(int(c["forecast_targets"]) for c in counted)
            lines.append(
                f"out of distribution: {flagged:,} of {total:,} forecasts in {len(counted)} log(s) "
                "(target speed or acceleration outside the model's training range; field "
                "out_of_distribution in /lanecast/prediction)"
            )
        return "\n".join(lines)


def clean_temporaries(out_dir: Path) -> list[Path]:
    """Remove the ``.<name>.tmp-*`` files and directories a killed run left anywhere in ``out_dir``."""
    removed = []
    for entry in sorted(Path(out_dir).rglob(".*.tmp-*"), reverse=True):  # outputs mirror a tree
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
        removed.append(entry)
    return removed


@contextlib.contextmanager
def locked(out_dir: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``out_dir`` (released by the OS if the process dies).

    The lock file is opened without following a symlink and without truncating: a planted
    ``OUT_DIR/.lanecast-annotate.lock`` symlink can neither redirect nor empty another file. It is
    removed when the run ends, refused or not, while still held: a run that opened it meanwhile
    finds its file gone once it holds it, and locks a new one.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    lock = out_dir / LOCK
    while True:
        try:  # never through a symlink, never blocking on a FIFO
            fd = open_regular(lock, os.O_WRONLY | os.O_CREAT)
        except FileNotFoundError as exc:
            raise not_ours(lock, exc) from exc
        with open(fd, "w") as f:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError as exc:
                raise InputError(
                    out_dir, "another `lanecast annotate` run is writing here", expected="one run per OUT_DIR"
                ) from exc
            if not _same_file(lock, os.fstat(fd)):
                continue  # removed by the run that held it: lock the file that is there now
            try:
                yield
            finally:
                lock.unlink(missing_ok=True)
                fcntl.flock(f, fcntl.LOCK_UN)
            return


def _same_file(path: Path, held: os.stat_result) -> bool:
    try:
        st = os.stat(path, follow_symlinks=False)
    except FileNotFoundError:
        return False
    return (st.st_dev, st.st_ino) == (held.st_dev, held.st_ino)


def model_identity(model_dir: Path | None) -> dict[str, str]:
    """The model that makes the forecasts: its name and the sha256 of its weights and card."""
    weights, card = resolve(model_dir)
    h = hashlib.sha256()
    for f in (weights, card):
        h.update(f.read_bytes())
    return {"name": weights.stem, "sha256": h.hexdigest()}


def run_options(options: AnnotateOptions, src: Path, model: dict[str, str] | None) -> dict[str, Any]:
    """What makes ``src``'s output, as the manifest records it (paths left out: they differ between
    machines, checksums do not)."""
    record: dict[str, Any] = {
        "every_s": options.every_s,
        "top_k": options.top_k,
        "encoding": options.encoding,
        "topic": options.topic,
    }
    if options.salvage:
        record["salvage"] = True
    if options.forecasts is not None:
        path = precomputed_forecasts_path(src, options.forecasts)
        record["forecasts_sha256"] = checksum(path) if path.is_file() else None
        record["frame_id"] = options.frame_id
    else:
        record["model"] = model
    return record


def inside(recorded: str) -> bool:
    """A recorded output name lanecast may write to: relative, below OUT_DIR, nothing hidden."""
    parts = Path(recorded).parts
    return (
        bool(parts)
        and not Path(recorded).is_absolute()
        and not any(p in ("..", ".") or p.startswith(".") for p in parts)
    )


def own_output(entry: dict[str, Any], output: Path, out_dir: Path) -> bool:
    """An entry's output is trusted only as this task's own output inside ``out_dir`` (no symlink on
    the way) whose checksum is the one recorded when it was written: a forged or stale line that
    points elsewhere, or at a file changed since, does not make a log "done"."""
    recorded = entry.get("output")
    if (
        not isinstance(recorded, str)
        or not isinstance(entry.get("output_sha256"), str)
        or not inside(recorded)
    ):
        return False
    if os.path.normpath(absolute(out_dir / recorded)) != os.path.normpath(absolute(output)):
        return False
    if output.is_symlink() or not output.exists():
        return False
    if os.path.realpath(output) != os.path.join(os.path.realpath(out_dir), recorded):
        return False
    return bool(checksum(output) == entry["output_sha256"])


def refuse_foreign_outputs(tasks: Sequence[Task], manifest: Manifest) -> None:
    """A file in OUT_DIR that the manifest does not name was not made by lanecast: never overwrite it."""
    claims = manifest.claims()
    foreign = [
        t.output
        for t in tasks
        if (t.output.exists() or t.output.is_symlink())
        and claims.get(relative_to_manifest(t.output, manifest.out_dir)) != str(t.input.resolve())
    ]
    if foreign:
        more = f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
        raise InputError(
            foreign[0],
            f"exists and was not written by lanecast annotate for this input ({manifest.path} records no such "
            f"output of it): refusing to overwrite it{more}",
            expected="a new --out, or that file moved away",
        )


def plan(
    inputs: Sequence[Path],
    out_dir: Path,
    manifest: Manifest,
    options: AnnotateOptions | None = None,
    *,
    root: Path | None = None,
    force: bool = False,
    model: dict[str, str] | None = None,
) -> tuple[list[Task], list[Path]]:
    """(tasks to run, inputs skipped as done); see the module docstring for the rules."""
    options = options or AnnotateOptions()
    inputs = [absolute(p) for p in inputs]
    root = root if root is not None else common_root(inputs)
    finished = manifest.finished()
    claims = manifest.claims()
    held = set(claims)
    todo, skipped = [], []
    for src in inputs:
        key = str(src.resolve())
        ours = [n for n, owner in claims.items() if owner == key and inside(n)]
        name = ours[-1] if ours else next(n for n in name_candidates(src, root) if n not in held)
        held.add(name)
        record = run_options(options, src, model)
        last = finished.get(key)
        if last is None:
            reason = "new"
        elif force:
            reason = "forced"
        elif last.get("status") != "done":
            reason = "failed before"
        elif last.get("options_key") != options_key(record):
            reason = "options changed"
        elif not own_output(last, out_dir / name, out_dir):
            reason = "output missing or changed"
        elif last.get("stat") != stat_signature(src) and last.get("sha256") != checksum(src):
            reason = "input changed"
        else:
            skipped.append(src)
            continue
        todo.append(Task(src, out_dir / name, record, reason))
    return todo, skipped


def run_bulk(
    paths: Sequence[Path],
    out_dir: Path,
    options: AnnotateOptions | None = None,
    *,
    workers: int = 1,
    engine: str = "local",
    address: str | None = None,
    retries: int = 2,
    force: bool = False,
) -> BulkResult:
    """Annotate every log named by ``paths`` into ``out_dir``; resume from its manifest.

    ``out_dir`` and the inputs are made absolute here, so that workers (other processes, Ray nodes
    with another working directory) read and write where the caller meant.
    """
    given, out_dir = Path(out_dir), absolute(out_dir)
    options = options or AnnotateOptions()
    if workers < 1:
        raise InputError(None, f"--workers must be at least 1, got {workers}")
    inputs = [absolute(p) for p in discover(paths, exclude=out_dir)]
    if not inputs:
        raise InputError(
            None, f"no logs found in {', '.join(map(str, paths))}", expected="*.mcap, *.bag or ROS 2 bags"
        )
    ray_started_here = ray_backend.connect(address, workers) if engine == "ray" else False  # fail fast
    created = not out_dir.exists()
    try:
        result = _run_bulk(
            inputs, paths, out_dir, options, workers=workers, engine=engine, retries=retries, force=force
        )
    finally:
        if ray_started_here:
            ray_backend.ray_module().shutdown()
    if created and result.failed and not result.done:
        _remove_failed_run(out_dir)
    result.out_as_given = given
    return result


def _remove_failed_run(out_dir: Path) -> None:
    """A run that made ``out_dir`` and annotated nothing leaves nothing: its manifest only records
    failures (stderr names them), and there is no work to resume."""
    (out_dir / MANIFEST).unlink(missing_ok=True)
    with contextlib.suppress(OSError):  # not empty: something else was put there meanwhile
        out_dir.rmdir()


def _run_bulk(
    inputs: list[Path],
    paths: Sequence[Path],
    out_dir: Path,
    options: AnnotateOptions,
    *,
    workers: int,
    engine: str,
    retries: int,
    force: bool,
) -> BulkResult:
    model = model_identity(options.model_dir) if options.forecasts is None else None
    result = BulkResult(out_dir=out_dir)
    if options.forecasts is None:
        result.model_line = provenance_line(provenance(options.model_dir))
    with locked(out_dir):
        clean_temporaries(out_dir)
        manifest = Manifest(out_dir)
        tasks, result.skipped = plan(
            inputs,
            out_dir,
            manifest,
            options,
            root=common_root(list(map(Path, paths))),
            force=force,
            model=model,
        )
        refuse_foreign_outputs(tasks, manifest)
        for task in tasks:  # claim every output name before any work (see lanecast.workflows.bulk.manifest)
            if task.reason != "new":
                result.redone[task.reason] = result.redone.get(task.reason, 0) + 1
            manifest.append(
                {
                    "input": str(task.input.resolve()),
                    "output": relative_to_manifest(task.output, out_dir),
                    "status": "started",
                    "reason": task.reason,
                    "options": task.options,
                    "options_key": options_key(task.options),
                    "lanecast": lanecast.__version__,
                }
            )
        progress = bar(desc="annotate", total=len(inputs), unit="log")
        progress.update(len(result.skipped))
        messages = 0

        def on_messages(n: int) -> None:
            nonlocal messages
            messages += n
            progress.set_postfix_str(f"{messages:,} msgs")

        def on_entry(task: Task, entry: dict[str, Any]) -> None:
            entry.update(
                output=relative_to_manifest(task.output, out_dir),
                options=task.options,
                options_key=options_key(task.options),
                lanecast=lanecast.__version__,
            )
            manifest.append(entry)
            result.given[len(result.entries)] = str(task.input)  # as named, links not followed
            result.entries.append(entry)
            progress.update(1)
            if entry["status"] == "failed":
                progress.write(f"lanecast annotate: FAILED {task.input}: {entry['error']}")

        try:
            if not tasks:
                pass
            elif engine == "ray":
                run_ray(tasks, options, on_entry, on_messages, out_dir=out_dir, retries=retries)
            elif workers == 1:
                run_inline(tasks, options, on_entry, on_messages)
            else:
                run_pool(tasks, options, on_entry, on_messages, workers=workers)
        finally:
            progress.close()
    return result
