"""Ray segments against triangle meshes: the coverage ray test shared by the
motion measures (:mod:`wearfit_usd.animate.measures`: coverage loss) and the
hidden body (:mod:`wearfit_usd.dress.hidden_body`)."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def ray_triangle(orig: np.ndarray, dirs: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                 t_min: float, t_max: float):
    """Two-sided ray / triangle intersection (Moller-Trumbore), row by row.

    orig, dirs (P, 3) rays (dirs unit), a, b, c (P, 3) triangle corners.
    Returns (hit (P,) bool: the ray meets the triangle at a parameter in
    [t_min, t_max], t (P,) that parameter (meaningless where not hit))."""
    e1 = b - a
    e2 = c - a
    p = np.cross(dirs, e2)
    det = np.einsum("ij,ij->i", e1, p)
    scale = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    ok = np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)
    inv = 1.0 / np.where(ok, det, 1.0)
    s = orig - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = np.einsum("ij,ij->i", dirs, q) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    tol = 1e-9
    hit = ok & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol) & (t >= t_min) & (t <= t_max)
    return hit, t


def cast_rays(orig: np.ndarray, dirs: np.ndarray, points: np.ndarray, faces: np.ndarray,
              t_min: float, t_max: float, chunk: int = 1024):
    """Nearest triangle of a mesh each ray segment meets.

    orig, dirs (R, 3) (dirs unit), mesh points (M, 3) and faces (F, 3);
    segments from ``orig + t_min dirs`` to ``orig + t_max dirs``. Candidate
    triangles: those whose centroid lies within half the segment plus the
    largest centroid-to-corner distance of the mesh from the segment's
    midpoint (a KD-tree over the centroids), tested exactly.

    Returns the hit triangle per ray (R,) int, -1 where none is met.
    """
    out = np.full(len(orig), -1, dtype=np.int64)
    if len(faces) == 0 or len(orig) == 0:
        return out
    tri = points[faces]
    cen = tri.mean(axis=1)
    reach = float(np.sqrt(np.max(np.einsum("fcj,fcj->fc", tri - cen[:, None], tri - cen[:, None]))))
    tree = cKDTree(cen)
    half = 0.5 * (t_max - t_min)
    mid = orig + dirs * (0.5 * (t_min + t_max))
    for s in range(0, len(orig), chunk):
        sl = slice(s, min(len(orig), s + chunk))
        lists = tree.query_ball_point(mid[sl], half + reach)
        lens = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
        if lens.sum() == 0:
            continue
        cand = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists if len(x)])
        ray = np.repeat(np.arange(sl.start, sl.stop), lens)
        hit, t = ray_triangle(orig[ray], dirs[ray], tri[cand, 0], tri[cand, 1], tri[cand, 2], t_min, t_max)
        if not hit.any():
            continue
        ray, cand, t = ray[hit], cand[hit], t[hit]
        order = np.lexsort((np.abs(t), ray))  # nearest hit first within each ray
        ray, cand = ray[order], cand[order]
        first = np.concatenate([[True], ray[1:] != ray[:-1]])
        out[ray[first]] = cand[first]
    return out
