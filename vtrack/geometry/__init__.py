"""Geometry core: SE(3) transforms, pinhole cameras, point clouds (numpy, float64)."""
