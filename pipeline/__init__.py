"""Stages that turn a track table into windows the network learns from (docs/design.md §2)."""
