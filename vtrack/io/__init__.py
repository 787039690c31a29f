"""Input/output: the session format (Zarr v3), standard streams, and PLY/GLB export."""
