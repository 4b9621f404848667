"""Shared fixtures for the whole test session."""

from __future__ import annotations

from pathlib import Path

import pytest

# A short simulated highD recording: 2 simulated minutes at medium density on a 500 m section
# (vehicles stay 12-25 s in view, so 8 s windows fit), seed 7. Wall time: a few seconds.
SIM_RECORDING = {
    "minutes": 2.0,
    "seed": 7,
    "lanes_per_direction": 3,
    "density": "medium",
    "truck_share": 0.2,
    "section_length_m": 500.0,
    "approach_length_m": 400.0,
}


@pytest.fixture(scope="session")
def sim_recording_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory with ``01_tracks.csv``, ``01_tracksMeta.csv``, ``01_recordingMeta.csv`` simulated once.

    highD format at 25 Hz, 3 lanes per direction (highD laneIds 2, 3, 4 upper and 6, 7, 8 lower),
    cars and trucks, lane changes with continuous lateral motion, neighbour ids from SUMO.
    Read it with ``lanecast.io_adapters.datasets.highd.read([sim_recording_dir])``; treat it as read-only.
    """
    from lanecast.io_adapters.sim import sumo_highway

    out = tmp_path_factory.mktemp("sim") / "highd-sim"
    return sumo_highway.simulate(out, show_progress=False, **SIM_RECORDING)  # type: ignore[arg-type]
