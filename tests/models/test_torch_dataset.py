"""WindowsDataset: a windows dataset directory served to torch, in one process and in DataLoader workers."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import synthetic_windows
from torch.utils.data import DataLoader

from lanecast.io_adapters.contracts.normalisation import NormStats, compute_stats, normalise
from lanecast.io_adapters.contracts.windows import labelled
from lanecast.io_adapters.errors import UsageError
from lanecast.io_adapters.windows_store.dataset import save_windows
from lanecast.models.torch_dataset import WindowsDataset


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_windows(synthetic_windows(400, seed=3), tmp_path_factory.mktemp("win") / "windows")


def test_samples_are_the_labelled_windows_of_the_split_normalised_with_training_statistics(
    dataset_dir: Path,
) -> None:
    w = synthetic_windows(400, seed=3)
    ds = WindowsDataset(dataset_dir, "test")
    rows = labelled(w, ("test",))
    assert len(ds) == len(rows) == 80
    stats = compute_stats(w.inputs, w.present, rows=labelled(w, ("train",)))
    sample = ds[5]
    row = int(rows[5])
    assert int(sample["index"]) == row
    expected = normalise(w.inputs[row : row + 1], w.present[row : row + 1], stats)[0]
    np.testing.assert_allclose(sample["inputs"].numpy(), expected, rtol=1e-6, atol=1e-6)
    assert sample["inputs"].shape == (4, 8, 30) and sample["inputs"].dtype == torch.float32
    np.testing.assert_array_equal(sample["present"].numpy(), w.present[row])
    np.testing.assert_array_equal(sample["maneuver"].numpy(), w.maneuver[row])
    np.testing.assert_array_equal(sample["future"].numpy(), w.future[row])
    assert float(sample["inputs"][:, 0].abs().sum()) == 0.0  # FL absent: exactly zero after normalising


def test_a_batch_keeps_the_order_asked_and_a_given_normalisation(dataset_dir: Path) -> None:
    stats = NormStats(np.array([1, 2, 3, 4], np.float32), np.array([2, 2, 2, 2], np.float32))
    ds = WindowsDataset(dataset_dir, "train", stats=stats)
    batch = ds.batch([9, 2, 7])
    assert batch["inputs"].shape == (3, 4, 8, 30)
    for k, i in enumerate([9, 2, 7]):
        torch.testing.assert_close(batch["inputs"][k], ds[i]["inputs"])
        assert int(batch["index"][k]) == int(ds.rows[i])
    w = synthetic_windows(400, seed=3)
    row = int(ds.rows[2])
    expected = normalise(w.inputs[row : row + 1], w.present[row : row + 1], stats)[0]
    np.testing.assert_allclose(batch["inputs"][1].numpy(), expected, rtol=1e-6)


@pytest.mark.parametrize("context", [None, "spawn"])
def test_dataloader_workers_serve_every_sample_once(dataset_dir: Path, context: str | None) -> None:
    ds = WindowsDataset(dataset_dir, "train")
    assert len(pickle.dumps(ds)) < 8 * len(ds) + 4_000  # the path and rows, no array data
    loader = DataLoader(ds, batch_size=64, num_workers=2, multiprocessing_context=context)
    batches = list(loader)
    index = torch.cat([b["index"] for b in batches]).numpy()
    np.testing.assert_array_equal(index, ds.rows)
    serial = ds.batch(list(range(len(ds))))
    torch.testing.assert_close(torch.cat([b["inputs"] for b in batches]), serial["inputs"])
    torch.testing.assert_close(torch.cat([b["maneuver"] for b in batches]), serial["maneuver"])


def test_an_unknown_split_or_index_is_refused(dataset_dir: Path) -> None:
    with pytest.raises(UsageError, match="split: 'tset' is not a split"):
        WindowsDataset(dataset_dir, "tset")
    ds = WindowsDataset(dataset_dir, "val")
    with pytest.raises(IndexError):
        ds[len(ds)]
