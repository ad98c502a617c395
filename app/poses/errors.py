"""Pose errors against ground truth, free of the unknown similarity between the two frames.

Poses are camera-to-world [V, 4, 4]. For every pair of views (i, j): the rotation error is the
angle of the estimated relative rotation R_i^T R_j against the true one; the translation
direction error is the angle between the directions from view i to view j expressed in view i's
camera frame. The scale error compares one distance (default first-to-last) with the truth.
Angles are degrees.
"""

from __future__ import annotations

import itertools

import numpy as np


def rotation_angle_deg(rot: np.ndarray) -> float:
    """Angle of a rotation matrix [3, 3] in degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1.0, 1.0))))


def pair_errors(est: np.ndarray, true: np.ndarray) -> list[dict]:
    """Per pair (i < j): {"pair", "rotation_deg", "translation_deg"}."""
    out = []
    for i, j in itertools.combinations(range(len(true)), 2):
        rel_e = est[i, :3, :3].T @ est[j, :3, :3]
        rel_t = true[i, :3, :3].T @ true[j, :3, :3]
        d_e = est[i, :3, :3].T @ (est[j, :3, 3] - est[i, :3, 3])
        d_t = true[i, :3, :3].T @ (true[j, :3, 3] - true[i, :3, 3])
        cos = d_e @ d_t / (np.linalg.norm(d_e) * np.linalg.norm(d_t))
        out.append(
            {
                "pair": [i, j],
                "rotation_deg": rotation_angle_deg(rel_e.T @ rel_t),
                "translation_deg": float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))),
            }
        )
    return out


def scale_error(est: np.ndarray, true: np.ndarray, i: int = 0, j: int = -1) -> float:
    """|d_est / d_true - 1| for the distance between views i and j."""
    d_e = np.linalg.norm(est[i, :3, 3] - est[j, :3, 3])
    d_t = np.linalg.norm(true[i, :3, 3] - true[j, :3, 3])
    return float(abs(d_e / d_t - 1.0))
