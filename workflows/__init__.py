"""The `lanecast` command line: one module per command, composing adapters, stages and models."""
