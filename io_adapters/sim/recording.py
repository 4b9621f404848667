"""A simulated highway recording: SUMO's samples (:mod:`~lanecast.io_adapters.sim.sumo_highway`)
written as highD's three CSV files (:mod:`~lanecast.io_adapters.sim.to_highd`)."""

from __future__ import annotations

import tempfile
from datetime import datetime
from pathlib import Path

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import check_output
from lanecast.io_adapters.progress import bar
from lanecast.io_adapters.sim.sumo_highway import HighwayConfig
from lanecast.io_adapters.sim.sumo_run import run_simulation
from lanecast.io_adapters.sim.to_highd import refuse_existing_recording, to_highd, write_highd


def simulate(
    out_dir: Path,
    *,
    minutes: float,
    seed: int,
    lanes_per_direction: int = 3,
    density: str = "medium",
    truck_share: float = 0.2,
    recording_id: int = 1,
    section_length_m: float = 1000.0,
    approach_length_m: float = 1000.0,
    lane_change_duration_s: float = 3.0,
    show_progress: bool = True,
    overwrite: bool = False,
    config: HighwayConfig | None = None,
    start: datetime | None = None,
) -> Path:
    """Simulate ``minutes`` of highway traffic and write a highD recording into ``out_dir``.

    ``config`` (e.g. a named scenario's, :mod:`lanecast.io_adapters.sim.scenarios`) replaces every
    other simulation argument. ``start``: when the recording began (its recordingMeta's month,
    weekday and time of day; drive logs made from it begin then); None: a fixed date. Returns ``out_dir``. The same arguments give byte-identical files. An
    existing recording of the same number in ``out_dir`` is refused before simulating, unless
    ``overwrite``.
    """
    cfg = config or HighwayConfig(
        minutes=minutes,
        seed=seed,
        lanes_per_direction=lanes_per_direction,
        density=density,
        truck_share=truck_share,
        section_length_m=section_length_m,
        approach_length_m=approach_length_m,
        lane_change_duration_s=lane_change_duration_s,
    )
    cfg.check()
    if not 1 <= recording_id <= 99:
        raise InputError(None, f"invalid recording id {recording_id}", expected="1 … 99")
    check_output(out_dir, directory=True)  # a file there, or on its path: before minutes of simulation
    if not overwrite:
        refuse_existing_recording(Path(out_dir), recording_id)
    total_s = cfg.warmup_s + cfg.n_frames / cfg.frame_rate
    with tempfile.TemporaryDirectory(prefix="lanecast-sumo-") as work:
        if show_progress:
            with bar(desc="simulating", total=round(total_s), unit="sim s") as progress_bar:
                samples = run_simulation(cfg, Path(work), lambda: progress_bar.update(1))
        else:
            samples = run_simulation(cfg, Path(work))
    tables = to_highd(samples, cfg, recording_id, start)
    return write_highd(tables, Path(out_dir), recording_id, overwrite=overwrite)
