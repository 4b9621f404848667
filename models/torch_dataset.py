"""A windows dataset as a ``torch.utils.data.Dataset``: train your own network on lanecast's windows.

:class:`WindowsDataset` serves the samples of one split of a windows dataset directory (written by
``lanecast windows``; docs/design.md §2) the way lanecast's own training sees them: the paper's
input tensor normalised with statistics of the training split (or a model's card), the presence
mask, the maneuver labels and the future offsets in metres.

The arrays are memory-mapped, and opened afresh in each process that reads them (a ``DataLoader``
worker, forked or spawned): the dataset pickles as its path and index list, never as array data, so
``DataLoader(num_workers=N)`` neither copies the dataset nor shares a file position between workers.
``__getitems__`` reads a whole batch with one sorted read of each memory map (torch's default
fetcher calls it when present); :meth:`WindowsDataset.batch` gives the batch as stacked tensors
without a ``DataLoader``.

Sample (a dict of tensors):
    inputs    float32 [4, 8, 30]  channels x, y, v, a (window frame), rows FL F FR L T R RL RR,
                                  oldest → t0; normalised, absent entries exactly 0
    present   bool    [8, 30]
    maneuver  int64   [5]         0 straight, 1 left, 2 right for t0+1 … t0+5 s
    future    float32 [5, 2]      the target's offsets (m) at t0+1 … t0+5 s, window frame
    index     int64   []          the window's row in the dataset (``windows.parquet``)
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from lanecast.io_adapters.contracts.normalisation import NormStats, compute_stats, normalise
from lanecast.io_adapters.contracts.windows import SPLITS, Windows, labelled
from lanecast.io_adapters.errors import UsageError
from lanecast.io_adapters.windows_store.dataset import load_windows

Sample = dict[str, torch.Tensor]


class WindowsDataset(Dataset[Sample]):
    """The labelled windows of ``split`` in the windows dataset at ``directory``.

    ``stats``: the input normalisation; default the training split's statistics (what
    ``lanecast train`` uses), or pass a model's (``NormStats.from_dict(card["normalisation"]["inputs"])``)
    to feed that model. Only windows whose future and maneuvers are all known are served.
    """

    def __init__(self, directory: str | Path, split: str = "train", stats: NormStats | None = None) -> None:
        if split not in SPLITS:
            raise UsageError("split", f"{split!r} is not a split", expected=f"one of {', '.join(SPLITS)}")
        self.directory = Path(directory)
        windows = load_windows(self.directory, mmap=True)
        self.rows = labelled(windows, (split,))
        if stats is None:
            train_rows = labelled(windows, ("train",))
            stats = compute_stats(windows.inputs, windows.present, rows=train_rows)
        self.stats = stats
        self._windows: Windows | None = windows
        self._pid = os.getpid()

    def __len__(self) -> int:
        return len(self.rows)

    def __getstate__(self) -> dict[str, Any]:
        """Pickled for a worker process: the path and rows, not the memory maps."""
        return {**self.__dict__, "_windows": None}

    def _opened(self) -> Windows:
        """The memory-mapped arrays, opened in this process."""
        if self._windows is None or self._pid != os.getpid():
            self._windows = load_windows(self.directory, mmap=True)
            self._pid = os.getpid()
        return self._windows

    def __getitem__(self, i: int) -> Sample:
        return self.__getitems__([i])[0]

    def __getitems__(self, indices: list[int]) -> list[Sample]:
        """The samples ``indices``, read together (views into one batch; the default collate stacks them)."""
        batch = self.batch(indices)
        return [{name: value[k] for name, value in batch.items()} for k in range(len(indices))]

    def batch(self, indices: list[int] | np.ndarray) -> Sample:
        """Samples ``indices`` as one batch: every tensor with a leading dimension of ``len(indices)``."""
        positions = np.asarray(indices, dtype=np.int64)
        if positions.size and (positions.min() < -len(self) or positions.max() >= len(self)):
            raise IndexError(f"sample index out of range for {len(self)} samples")
        rows = self.rows[positions]
        order = np.argsort(rows, kind="stable")  # sequential reads of the memory maps
        back = np.empty_like(order)
        back[order] = np.arange(order.size)
        sorted_rows = rows[order]
        w = self._opened()
        inputs = np.asarray(w.inputs[sorted_rows])
        present = np.asarray(w.present[sorted_rows])
        return {
            "inputs": torch.from_numpy(normalise(inputs, present, self.stats)[back]),
            "present": torch.from_numpy(present[back]),
            "maneuver": torch.from_numpy(np.asarray(w.maneuver[sorted_rows])[back]),
            "future": torch.from_numpy(np.asarray(w.future[sorted_rows], dtype=np.float32)[back]),
            "index": torch.from_numpy(rows.astype(np.int64)),
        }
