"""io_adapters/datasets/highd."""
