"""io_adapters/logs/foxglove."""
