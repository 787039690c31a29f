"""Per-frame processing of camera frames (segmentation, ...)."""
