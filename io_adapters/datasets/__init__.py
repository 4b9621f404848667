"""Dataset readers: highD, NGSIM, lanecast's own Parquet track tables."""
