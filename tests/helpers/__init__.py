"""Test helpers shared by several test modules (importable with pythonpath = tests)."""
