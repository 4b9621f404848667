"""models/reports."""
