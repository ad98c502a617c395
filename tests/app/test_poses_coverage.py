"""`panogrf.app.scene.coverage`: the warning when a camera leaves the region the sources cover."""

from __future__ import annotations

import numpy as np

from panogrf.app.scene.coverage import covered_radius, frame_ranges, path_warning, uncovered


def _at(*xs):
    c2w = np.stack([np.eye(4)] * len(xs))
    c2w[:, 0, 3] = xs
    return c2w


def test_middle_of_a_triplet_is_covered_and_far_frames_are_named():
    sources = _at(0.0, 2.0)
    assert covered_radius(sources) == 1.5
    path = _at(0.0, 1.0, 2.0, 3.2, 3.6, 5.0, 1.0)
    np.testing.assert_array_equal(uncovered(path, sources), [0, 0, 0, 0, 1, 1, 0])
    warning = path_warning(path, sources)
    assert warning.startswith("warning: 2 of 7 frames") and "frames 4-5;" in warning
    assert path_warning(path[:3], sources) is None
    assert covered_radius(_at(0.0)) == 0.5  # one source: the minimum radius


def test_frame_ranges():
    assert frame_ranges(np.array([3, 4, 5, 9, 11, 12])) == "3-5, 9, 11-12"
    assert frame_ranges(np.array([], int)) == ""
