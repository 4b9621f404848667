"""conv-social-pooling's research ``.mat`` sets (``traj`` and ``tracks`` in TrainSet.mat, ValSet.mat,
TestSet.mat), as its ``preprocess_data.m`` writes them, from raw NGSIM files or highD recordings:
``writer`` (write_csp), ``inputs``, ``sets``, ``fields``, ``matfile``; ``cli`` for ``convert --to csp``."""
