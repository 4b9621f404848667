"""conv-social-pooling's research ``.mat`` sets (``traj`` and ``tracks`` in TrainSet.mat, ValSet.mat,
TestSet.mat), as its ``preprocess_data.m`` writes them, from raw NGSIM files or highD recordings."""

from lanecast.io_adapters.datasets.csp.writer import CONVENTIONS, MANIFEST, check_csp_output, write_csp

__all__ = ["CONVENTIONS", "MANIFEST", "check_csp_output", "write_csp"]
