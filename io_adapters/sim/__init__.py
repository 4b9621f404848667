"""The SUMO highway simulator, written as highD-format recordings."""
