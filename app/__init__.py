"""Application layer: CLI, scene files, synthetic data, the viewer. Imports renderer and model."""
