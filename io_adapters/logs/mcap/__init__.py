"""io_adapters/logs/mcap."""
