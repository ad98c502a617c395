"""Pure torch: spherical geometry, networks and metrics. No GL, no file I/O."""
