"""The contracts every part relies on, each defined once: track table, windows, forecasts."""
