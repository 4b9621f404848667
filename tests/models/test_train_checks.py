"""Training configs on hostile input: a bad model, kernels larger than the window, a FIFO; refused
before torch is loaded or the file is read."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from lanecast.io_adapters.errors import InputError


@pytest.mark.parametrize(
    ("model", "column"),
    [
        (5, "model"),
        ({"hidden": -3}, "model.hidden"),
        ({"hidden": 10**8}, "model.hidden"),
        ({"conv_kernels": [[3, 3]]}, "model.conv_kernels"),
    ],
)
def test_training_config_with_a_bad_model_is_refused_before_torch(
    tmp_path: Path, model: object, column: str
) -> None:
    from lanecast.models.train import TrainConfig

    config = tmp_path / "config.json"
    config.write_text(json.dumps({"epochs": 1, "model": model}))
    with pytest.raises(InputError) as err:
        TrainConfig.from_file(config)
    assert err.value.path == str(config)
    assert err.value.column == column


def test_training_config_with_kernels_larger_than_the_window_is_refused(tmp_path: Path) -> None:
    from lanecast.models.train import TrainConfig

    config = tmp_path / "config.json"
    config.write_text(json.dumps({"model": {"conv_kernels": [[9, 30], [3, 3], [2, 3], [1, 1]]}}))
    with pytest.raises(InputError, match="conv1 leaves no output"):
        TrainConfig.from_file(config)


def test_a_training_config_that_is_a_fifo_is_refused_without_reading_it(tmp_path: Path) -> None:
    """`--config` naming a FIFO blocked forever, /dev/zero ran out of memory (MemoryError traceback)."""
    import threading

    from lanecast.models.train import TrainConfig

    fifo = tmp_path / "config.json"
    os.mkfifo(fifo)

    def unblock() -> None:  # should the read block again, give it a document: the test fails, not hangs
        with open(fifo, "w") as fh:
            fh.write("{}")

    writer = threading.Timer(5.0, unblock)
    writer.daemon = True
    writer.start()
    try:
        with pytest.raises(InputError, match="not a regular file") as err:
            TrainConfig.from_file(fifo)
    finally:
        writer.cancel()
    assert err.value.path == str(fifo)
