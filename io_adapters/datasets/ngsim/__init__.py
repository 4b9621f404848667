"""io_adapters/datasets/ngsim."""
