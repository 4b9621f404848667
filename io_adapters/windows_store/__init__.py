"""io_adapters/windows_store."""
