"""io_adapters/datasets/parquet."""
