"""CLI command modules; each defines ``register(app)``. Keep heavy imports inside the commands."""
