"""A scene and its session: the folder format (`folder`, `types`, `check`), the on-disk cache of
its prepared depth and features (`cache`), coverage and consistency checks, and `session`, the
library layer that loads, estimates, caches and renders for the commands."""
