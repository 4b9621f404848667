"""The ST-CNN of Mersch et al. (IROS 2021), its baselines, training, prediction and metrics."""
