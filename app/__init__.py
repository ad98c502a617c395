"""Application layer: CLI, scene files, synthetic data, (later) the viewer. Imports renderer and model."""
