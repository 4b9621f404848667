"""io_adapters/logs/messages."""
