"""Adapters between the outside world's formats and lanecast's track table (docs/design.md §1).

This package imports neither ``pipeline`` nor ``models``.
"""
