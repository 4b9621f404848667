"""Forecasts written into drive logs: message encoders and the byte-for-byte log copy."""
