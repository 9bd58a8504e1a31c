"""The per-frame layer pass's ray search (:mod:`animate.layer_hold`):
compiled kernel and its numpy twin.

For each row r (an outer-layer vertex), a ray from ``top[r]`` along
``dirs[r]`` (the body normal, pointing down: ``top`` lies ``reach`` above
the vertex) is met against the candidate triangles ``cand[r]`` (indices
into ``faces``, padded with -1); the nearest hit with ``0 <= t <=
reach_down[r]`` is the inner surface's top. Two-sided Moller-Trumbore, as
:func:`geometry.rays.ray_triangle`.

points (M, 3) float64, faces (F, 3) int64, cand (R, C) int64, top and dirs
(R, 3) float64 (dirs unit), reach_down (R,) float64. Returns t (R,), inf
where no candidate is met, and the triangle met (R,), -1 where none.
"""
from __future__ import annotations

import numpy as np

from ..geometry.rays import ray_triangle
from .jit import HAVE_NUMBA, jit

_TOL = 1e-9


@jit
def _first_hits(points, faces, cand, top, dirs, reach_down, out, out_face):
    for r in range(cand.shape[0]):
        ox, oy, oz = top[r, 0], top[r, 1], top[r, 2]
        dx, dy, dz = dirs[r, 0], dirs[r, 1], dirs[r, 2]
        best = np.inf
        best_f = -1
        for k in range(cand.shape[1]):
            f = cand[r, k]
            if f < 0:
                continue
            a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
            e1x = points[b, 0] - points[a, 0]
            e1y = points[b, 1] - points[a, 1]
            e1z = points[b, 2] - points[a, 2]
            e2x = points[c, 0] - points[a, 0]
            e2y = points[c, 1] - points[a, 1]
            e2z = points[c, 2] - points[a, 2]
            px = dy * e2z - dz * e2y
            py = dz * e2x - dx * e2z
            pz = dx * e2y - dy * e2x
            det = e1x * px + e1y * py + e1z * pz
            scale = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z) * np.sqrt(e2x * e2x + e2y * e2y + e2z * e2z)
            if abs(det) <= 1e-12 * max(scale, 1e-300):
                continue
            inv = 1.0 / det
            sx = ox - points[a, 0]
            sy = oy - points[a, 1]
            sz = oz - points[a, 2]
            u = (sx * px + sy * py + sz * pz) * inv
            if u < -_TOL or u > 1.0 + _TOL:
                continue
            qx = sy * e1z - sz * e1y
            qy = sz * e1x - sx * e1z
            qz = sx * e1y - sy * e1x
            v = (dx * qx + dy * qy + dz * qz) * inv
            if v < -_TOL or u + v > 1.0 + _TOL:
                continue
            t = (e2x * qx + e2y * qy + e2z * qz) * inv
            if 0.0 <= t <= reach_down[r] and t < best:
                best = t
                best_f = f
        out[r] = best
        out_face[r] = best_f


def first_hits_numpy(points: np.ndarray, faces: np.ndarray, cand: np.ndarray, top: np.ndarray, dirs: np.ndarray,
                     reach_down: np.ndarray) -> np.ndarray:
    """:func:`first_hits` in numpy (every candidate pair at once)."""
    r, k = np.nonzero(cand >= 0)
    out = np.full(len(cand), np.inf)
    face = np.full(len(cand), -1, dtype=np.int64)
    if len(r) == 0:
        return out, face
    tri = points[faces[cand[r, k]]]
    hit, t = ray_triangle(top[r], dirs[r], tri[:, 0], tri[:, 1], tri[:, 2], 0.0, float(reach_down.max()))
    hit &= t <= reach_down[r]
    r, k, t = r[hit], k[hit], t[hit]
    # per row the nearest hit (the first of equal ones in candidate order)
    by = np.lexsort((k, t, r))
    first = np.r_[True, r[by][1:] != r[by][:-1]]
    out[r[by][first]] = t[by][first]
    face[r[by][first]] = cand[r[by][first], k[by][first]]
    return out, face


def first_hits(points: np.ndarray, faces: np.ndarray, cand: np.ndarray, top: np.ndarray, dirs: np.ndarray,
               reach_down: np.ndarray) -> np.ndarray:
    """(R,) the nearest hit of each row's ray among its candidate triangles
    (see the module), inf where none, and (R,) the triangle met, -1 where
    none."""
    if not HAVE_NUMBA:
        return first_hits_numpy(points, faces, cand, top, dirs, reach_down)
    out = np.empty(len(cand))
    out_face = np.empty(len(cand), dtype=np.int64)
    _first_hits(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64),
                np.ascontiguousarray(cand, dtype=np.int64), np.ascontiguousarray(top, dtype=np.float64),
                np.ascontiguousarray(dirs, dtype=np.float64), np.ascontiguousarray(reach_down, dtype=np.float64),
                out, out_face)
    return out, out_face
