"""workflows/bulk."""
