"""Autoware perception messages beyond the tracked objects: recorded predictions, lanecast forecasts as PredictedObjects."""
