"""Rendering of novel views from a scene cache (depends on `model`)."""
