"""workflows/annotation."""
