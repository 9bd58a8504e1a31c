"""Rigid/affine transform helpers on plain numpy arrays.

Convention (the same as USD's Gf): matrices are 4x4 and act on ROW vectors,
``p' = [p, 1] @ M``; the translation lives in ``M[3, :3]``. Composition reads
left to right: ``A @ B`` applies A first, then B. A joint's world transform is
``world[j] = local[j] @ world[parent[j]]``.

Quaternions are ``(w, x, y, z)`` (real first, like ``Gf.Quatf``), unit length,
and ``matrix_from_quat`` returns the 3x3 block of a row-vector matrix.
Euler angles (:func:`euler_to_matrix`, :func:`matrix_to_euler`,
:func:`axis_rotation`) follow BVH: the rotations listed left to right are
intrinsic (column-vector ``R_0 @ R_1 @ R_2``), angles in degrees.
Every function is vectorised over leading axes ``(...)``.
"""
from __future__ import annotations

import numpy as np

# Internal world frame: Y up, metres. Stage Z-up -> internal Y-up maps
# (x, y, z) -> (x, z, -y)  (row-vector matrix below).
Z_UP_TO_Y_UP = np.array(
    [[1.0, 0.0, 0.0, 0.0],
     [0.0, 0.0, -1.0, 0.0],
     [0.0, 1.0, 0.0, 0.0],
     [0.0, 0.0, 0.0, 1.0]])


def stage_to_internal(up_axis: str, meters_per_unit: float) -> np.ndarray:
    """(4, 4) row-vector matrix taking stage world coordinates to internal
    world coordinates (Y up, metres)."""
    m = np.eye(4) * float(meters_per_unit)
    m[3, 3] = 1.0
    if str(up_axis).upper() == "Z":
        m = m @ Z_UP_TO_Y_UP
    return m


def transform_points(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) row-vector matrix to (N, 3) points -> (N, 3)."""
    return points @ matrix[:3, :3] + matrix[3, :3]


def make_matrix(rotation: np.ndarray | None = None,
                translation: np.ndarray | None = None,
                scale: np.ndarray | None = None) -> np.ndarray:
    """Compose scale, then rotation (3x3 row-vector block), then translation.

    Shapes broadcast over leading axes: rotation (..., 3, 3),
    translation (..., 3), scale (..., 3). Returns (..., 4, 4).
    """
    lead = ()
    for a, trail in ((rotation, 2), (translation, 1), (scale, 1)):
        if a is not None:
            a = np.asarray(a)
            lead = np.broadcast_shapes(lead, a.shape[:a.ndim - trail])
    m = np.zeros(lead + (4, 4))
    r = np.broadcast_to(np.eye(3), lead + (3, 3)) if rotation is None else rotation
    if scale is not None:
        r = np.asarray(scale)[..., :, None] * r
    m[..., :3, :3] = r
    if translation is not None:
        m[..., 3, :3] = translation
    m[..., 3, 3] = 1.0
    return m


def quat_normalize(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3) row-vector rotations."""
    q = quat_normalize(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    # Column-vector rotation matrix R; row-vector form is R.T.
    r = np.empty(q.shape[:-1] + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y + w * z)
    r[..., 0, 2] = 2 * (x * z - w * y)
    r[..., 1, 0] = 2 * (x * y - w * z)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z + w * x)
    r[..., 2, 0] = 2 * (x * z + w * y)
    r[..., 2, 1] = 2 * (y * z - w * x)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def quat_from_matrix(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) row-vector rotations -> (..., 4) unit quaternions (w>=0)."""
    r = np.asarray(r, dtype=float)
    m = np.swapaxes(r, -1, -2)  # column-vector form
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    cand = np.stack([
        1 + m00 + m11 + m22,
        1 + m00 - m11 - m22,
        1 - m00 + m11 - m22,
        1 - m00 - m11 + m22], axis=-1)
    k = np.argmax(cand, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300)) * 2
    q = np.empty(r.shape[:-2] + (4,))
    # case 0 (w largest)
    q0 = np.stack([s / 4, (m[..., 2, 1] - m[..., 1, 2]) / s,
                   (m[..., 0, 2] - m[..., 2, 0]) / s, (m[..., 1, 0] - m[..., 0, 1]) / s], -1)
    q1 = np.stack([(m[..., 2, 1] - m[..., 1, 2]) / s, s / 4,
                   (m[..., 0, 1] + m[..., 1, 0]) / s, (m[..., 0, 2] + m[..., 2, 0]) / s], -1)
    q2 = np.stack([(m[..., 0, 2] - m[..., 2, 0]) / s, (m[..., 0, 1] + m[..., 1, 0]) / s,
                   s / 4, (m[..., 1, 2] + m[..., 2, 1]) / s], -1)
    q3 = np.stack([(m[..., 1, 0] - m[..., 0, 1]) / s, (m[..., 0, 2] + m[..., 2, 0]) / s,
                   (m[..., 1, 2] + m[..., 2, 1]) / s, s / 4], -1)
    q = np.choose(k[..., None], [q0, q1, q2, q3])
    q = np.where(q[..., :1] < 0, -q, q)
    return quat_normalize(q)


def quat_slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical interpolation, shortest arc. q0, q1 (..., 4); t broadcastable
    to (...)."""
    q0 = quat_normalize(q0)
    q1 = quat_normalize(q1)
    t = np.asarray(t, float)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(theta)
    small = sin < 1e-6
    safe = np.where(small, 1.0, sin)
    w0 = np.where(small, 1 - t, np.sin((1 - t) * theta) / safe)
    w1 = np.where(small, t, np.sin(t * theta) / safe)
    return quat_normalize(w0 * q0 + w1 * q1)


def decompose(m: np.ndarray):
    """Split (..., 4, 4) affine row-vector matrices into translation (..., 3),
    rotation (..., 3, 3) (proper, det +1) and per-axis scale (..., 3), such
    that ``make_matrix(rotation, translation, scale)`` rebuilds ``m`` when it
    has no shear."""
    m = np.asarray(m, float)
    a = m[..., :3, :3]
    scale = np.linalg.norm(a, axis=-1)
    det = np.linalg.det(a)
    scale[..., 0] = np.where(det < 0, -scale[..., 0], scale[..., 0])
    safe = np.where(np.abs(scale) < 1e-300, 1.0, scale)
    rot = a / safe[..., :, None]
    # re-orthonormalise (polar) to absorb float noise
    u, _, vt = np.linalg.svd(rot)
    rot = u @ vt
    return m[..., 3, :3].copy(), rot, scale


def rotation_part(m: np.ndarray) -> np.ndarray:
    """Nearest proper rotation (..., 3, 3) to the 3x3 block of (..., 4, 4) or
    (..., 3, 3) matrices (polar decomposition)."""
    a = np.asarray(m, float)[..., :3, :3]
    u, _, vt = np.linalg.svd(a)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation (row-vector 3x3) taking direction a to direction b.
    a, b (..., 3) -> (..., 3, 3)."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-300)
    b = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-300)
    v = np.cross(a, b)
    c = np.sum(a * b, axis=-1)
    # antiparallel: pick any perpendicular axis
    anti = c < -1 + 1e-9
    if np.any(anti):
        alt = np.where(np.abs(a[..., :1]) < 0.9, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
        perp = np.cross(a, alt)
        perp /= np.linalg.norm(perp, axis=-1, keepdims=True)
        v = np.where(anti[..., None], perp, v)
    w = np.where(anti, 0.0, 1.0 + c)
    q = np.concatenate([w[..., None], v], axis=-1)
    q = np.where(anti[..., None], np.concatenate([np.zeros_like(w)[..., None], v], -1), q)
    return matrix_from_quat(quat_normalize(q))


def invert(m: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) affine matrices."""
    return np.linalg.inv(m)


# --------------------------------------------------------------------------
# Euler angles (BVH semantics: the channel order as listed, intrinsic)

_EULER_AXES = "XYZ"


def axis_rotation(axis: int, angle_rad: np.ndarray) -> np.ndarray:
    """Row-vector rotation matrices (..., 3, 3) about one coordinate axis."""
    c = np.cos(angle_rad)
    s = np.sin(angle_rad)
    m = np.zeros(np.shape(angle_rad) + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[..., axis, axis] = 1.0
    # column-vector R has R[i,i]=c, R[i,j]=-s, R[j,i]=s, R[j,j]=c; row form = R.T
    m[..., i, i] = c
    m[..., j, j] = c
    m[..., i, j] = s
    m[..., j, i] = -s
    return m


def euler_to_matrix(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """BVH Euler angles -> row-vector rotation matrices.

    angles_deg: (..., k) degrees, one column per letter of ``order``
        (``order`` = the rotation channels as listed in the file, e.g. "ZXY",
        k = len(order), 0..3 letters, no repeats).
    Returns (..., 3, 3): the row-vector form of the column-vector product
    ``R_order[0] @ R_order[1] @ R_order[2]`` (intrinsic rotations, BVH
    semantics), i.e. ``r[2] @ r[1] @ r[0]`` in row-vector matrices.
    """
    angles = np.asarray(angles_deg, dtype=np.float64)
    order = order.upper()
    if len(order) != angles.shape[-1]:
        raise ValueError(f"order {order!r} needs {len(order)} angles, got {angles.shape[-1]}")
    out = np.broadcast_to(np.eye(3), angles.shape[:-1] + (3, 3)).copy()
    rad = np.deg2rad(angles)
    for k, letter in enumerate(order):
        out = axis_rotation(_EULER_AXES.index(letter), rad[..., k]) @ out
    return out


def matrix_to_euler(rot: np.ndarray, order: str = "ZYX") -> np.ndarray:
    """Row-vector rotation matrices (..., 3, 3) -> Euler angles (..., 3) in
    degrees for a 3-letter BVH channel ``order`` (inverse of
    :func:`euler_to_matrix`; at gimbal lock the last angle is set to 0)."""
    order = order.upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise ValueError(f"rotation order must be a permutation of XYZ, got {order!r}")
    m = np.swapaxes(np.asarray(rot, dtype=np.float64), -1, -2)  # column-vector form
    i, j, k = (_EULER_AXES.index(c) for c in order)
    # M = R_i(a) R_j(b) R_k(c); parity of the permutation (i, j, k)
    sign = 1.0 if (j - i) % 3 == 1 else -1.0
    sb = np.clip(sign * m[..., i, k], -1.0, 1.0)
    b = np.arcsin(sb)
    a = np.arctan2(-sign * m[..., j, k], m[..., k, k])
    c = np.arctan2(-sign * m[..., i, j], m[..., i, i])
    lock = np.abs(sb) > 1 - 1e-9
    if np.any(lock):
        # c := 0; then a from the j/k block of M = R_i(a) R_j(b)
        a_lock = np.arctan2(sign * m[..., k, j], m[..., j, j])
        a = np.where(lock, a_lock, a)
        c = np.where(lock, 0.0, c)
    return np.rad2deg(np.stack([a, b, c], axis=-1))
