"""Poses for one's own captures: estimated from plain 360-degree panoramas, or imported.

- `panogrf.app.poses.features`: SIFT on cube faces rendered from a panorama, unit bearings,
  ratio-tested and cross-checked matches, guided matching along epipolar planes.
- `panogrf.app.poses.colmap`: the pipeline for V views: those features and matches, COLMAP's
  verification, global mapping and bundle adjustment (pycolmap), a report per pair and view.
- `panogrf.app.poses.colmap_report`: the poses and that report made from COLMAP's reconstruction
  (or from the best verified pair alone).
- `panogrf.app.poses.geometry`: triangulation of a pair and
  bundle adjustment on angular residuals (the two-view case).
- `panogrf.app.poses.scale`: upright (floor plane or level cameras), metric scale from a camera
  height or a known distance, the canonical world frame.
- `panogrf.app.poses.importers`: TUM trajectories (stella_vslam / OpenVSLAM), OpenSfM
  ``reconstruction.json`` (spherical cameras), COLMAP ``images.txt`` of cube-face views.
- `panogrf.app.poses.errors`: pose errors against ground truth (relative rotation, translation
  direction, scale) for tests and the benchmark.

Conventions are the project's (docs/conventions.md): camera-to-world 4x4 (``c2w``), OpenGL
camera frame (x right, y up, looking down -z), metres, world y up with the floor at y = 0 where
a floor was found. Other tools' camera frames are OpenCV's (x right, y down, looking down +z):
``c2w_gl[:3, :3] = c2w_cv[:3, :3] @ diag(1, -1, -1)`` (`CV_TO_GL`).
"""

from __future__ import annotations

import numpy as np

#: Right-multiplying a camera-to-world rotation in the OpenCV camera frame by this gives the
#: OpenGL one (and back: it is its own inverse).
CV_TO_GL = np.diag([1.0, -1.0, -1.0])
