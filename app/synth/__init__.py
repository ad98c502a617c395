"""Procedural indoor 360-degree scenes rendered headless (EGL): the project's training and test data."""
