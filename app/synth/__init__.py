"""Procedural indoor 360-degree scenes rendered headless (EGL): training and test data."""
