"""Stages that turn a track table into windows the network learns from (DESIGN.md §2)."""
