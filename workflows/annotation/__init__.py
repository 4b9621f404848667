"""Forecasts in drive logs: a log annotated end to end, a track table's forecasts, annotated logs' scores."""
