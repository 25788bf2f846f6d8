"""Base orientations and rotation helpers shared by the predictor and the twin.

Conventions: ``up`` is the identity (backbone along world +z); ``horizontal`` is the
thesis's set-up, the base rotated +90° about world y: local x → world −z, local y → world +y,
local z → world +x, with gravity along world −z.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["HORIZONTAL", "HORIZONTAL_QUAT", "UP", "pose_name", "rotation_of_quat", "base_rotation_from", "quat_to_matrix", "matrix_to_quat", "rot_x", "rot_y", "rot_z"]


def rot_x(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


UP = np.eye(3)
HORIZONTAL = rot_y(np.pi / 2)


def quat_to_matrix(quat) -> np.ndarray:
    """Rotation matrix of a quaternion ``(w, x, y, z)``; normalised, refuses a zero quaternion."""
    q = np.asarray(quat, dtype=float)
    norm = np.linalg.norm(q)
    if q.shape != (4,) or not np.isfinite(norm) or norm < 1e-12:
        raise ValueError(f"quaternion {quat!r}: expected 4 finite numbers, not all zero")
    w, x, y, z = q / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quat(rot) -> np.ndarray:
    """Quaternion ``(w, x, y, z)`` with w >= 0 of a rotation matrix (Shepperd's method)."""
    m = np.asarray(rot, dtype=float).tolist()
    t = m[0][0] + m[1][1] + m[2][2]
    if t > 0:
        s = 2.0 * math.sqrt(1.0 + t)
        q = [0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s]
    else:
        i = max(range(3), key=lambda n: m[n][n])
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(1.0 + m[i][i] - m[j][j] - m[k][k])
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (m[k][j] - m[j][k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j][i] + m[i][j]) / s
        q[1 + k] = (m[k][i] + m[i][k]) / s
    quat = np.array(q)
    return quat if quat[0] >= 0 else -quat


# The thesis's horizontal clamp as a quaternion (w, x, y, z): (cos 45°, 0, sin 45°, 0).
HORIZONTAL_QUAT = tuple(float(v) for v in matrix_to_quat(HORIZONTAL))
_NAMED = {"up": UP, "horizontal": HORIZONTAL}
_NAMED_QUATS = [(matrix_to_quat(rotation), rotation) for rotation in _NAMED.values()]


def rotation_of_quat(quat) -> np.ndarray:
    """:func:`quat_to_matrix`, except that the quaternion of a named pose gives that pose's own
    matrix, so that a twin built from a parameter file's quaternion and one built from the name
    are the same model, bit for bit."""
    q = np.asarray(quat, dtype=float)
    norm = np.linalg.norm(q)
    if q.shape == (4,) and np.isfinite(norm) and norm > 1e-12:
        for named, rotation in _NAMED_QUATS:
            if np.allclose(q / norm, named, rtol=0.0, atol=1e-12):
                return rotation.copy()
    return quat_to_matrix(q)


def base_rotation_from(*, pose: str | None = None, quat=None) -> np.ndarray:
    """Base rotation (3×3, body → world) from a named pose or a quaternion ``(w, x, y, z)``."""
    if quat is not None:
        return rotation_of_quat(quat)
    if pose in _NAMED:
        return _NAMED[pose].copy()
    raise ValueError(f"pose {pose!r}: expected 'up' or 'horizontal'")


def pose_name(rotation) -> str:
    """The clamp pose in words, for reports: ``"horizontal"`` and ``"upright"`` for the named
    poses, else where the backbone points, e.g. ``"pointing 30° below the horizontal"``
    (the body z axis against world z; gravity along world −z)."""
    r = np.asarray(rotation, dtype=float)
    if np.allclose(r, HORIZONTAL, atol=1e-9):
        return "horizontal (the thesis's clamp)"
    if np.allclose(r, UP, atol=1e-9):
        return "upright"
    axis = r[:, 2]
    elevation = math.degrees(math.asin(max(-1.0, min(1.0, float(axis[2])))))
    if abs(elevation) < 0.05:
        return "pointing horizontally"
    if elevation >= 89.95:
        return "pointing straight up"
    if elevation <= -89.95:
        return "pointing straight down"
    return f"pointing {abs(elevation):.3g}° {'above' if elevation > 0 else 'below'} the horizontal"
