"""vtrack applications: the ``vtrack`` command-line interface and the viewer app."""
