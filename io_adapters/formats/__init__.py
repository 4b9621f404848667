"""io_adapters/formats."""
