"""Training: data in memory, loops for the depth networks (and later the renderer)."""
