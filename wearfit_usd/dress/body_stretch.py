"""The body's own local stretch between two poses or shapes of one body
topology, as a range of edge-length ratios for item edges bound to it
(plain numpy).

An item edge that follows the body changes length by at most the body's
stretch under it: from the smallest to the largest principal stretch of the
body triangles its endpoints are bound to, widened by the offset factor of
its clearance (an offset surface over a skin that bends more grows more).
:func:`metrics.shape_change` judges redressed items by this range and
:func:`untangle.relax_edges` keeps them inside it.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..geometry.closest import VertexNormals, point_and_normal


def offset_factor(ref_body, fit_body, body_faces, tri, bary, clearance, e, edge_len, normals=None):
    """(E,) growth of item edges (E, 2) (reference lengths ``edge_len``)
    over the growth of the skin under them that comes from the item's
    clearance alone: an offset surface at distance c over skin of normal
    curvature k along the edge is ``1 + c k`` times as long as the skin, so
    the factor is ``(1 + c k_fit) / (1 + c k_ref)``. The curvature along the
    edge is the discrete normal derivative between its endpoints' closest
    skin points, ``(n_j - n_i) . (p_j - p_i) / |p_j - p_i|^2``, with the same
    skin points (triangle ``tri`` (M,), barycentrics ``bary`` (M, 3)) on both
    bodies; c (m) is the endpoints' mean reference ``clearance`` (M,), 0 if
    inside. Factor 1 where the skin points are less than a third of the
    edge apart (an edge standing off the skin, e.g. along a hair strand) or
    where an offset exceeds half the curvature radius of a concave part
    (``1 + c k <= 0.5``: the offset surface folds there). ``normals``: the
    two bodies' vertex normals (N, 3) if already computed (per frame of an
    animation)."""
    if normals is None:
        vn = VertexNormals(body_faces, len(ref_body))
        normals = (vn(ref_body), vn(fit_body))
    c = np.maximum(0.5 * (clearance[e[:, 0]] + clearance[e[:, 1]]), 0.0)
    used, e = np.unique(e, return_inverse=True)  # only the edges' own vertices
    e = e.reshape(-1, 2)
    tri, bary = tri[used], bary[used]
    grow, apart = [], None
    for body, normal in zip((ref_body, fit_body), normals):
        p, n = point_and_normal(body, normal, body_faces, tri, bary)
        dp = p[e[:, 1]] - p[e[:, 0]]
        l2 = np.einsum("ei,ei->e", dp, dp)
        if apart is None:
            apart = l2 > (edge_len / 3.0) ** 2
        grow.append(1.0 + c * np.einsum("ei,ei->e", n[e[:, 1]] - n[e[:, 0]], dp) / np.maximum(l2, 1e-300))
    a, b = grow
    return np.where(apart & (a > 0.5) & (b > 0.5), b / np.maximum(a, 0.5), 1.0)


def triangle_grams(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(T, 3) the Gram entries (e1.e1, e1.e2, e2.e2) of each triangle's
    edges e1 = v2 - v1, e2 = v3 - v1 on points (N, 3)."""
    e1 = points[faces[:, 1]] - points[faces[:, 0]]
    e2 = points[faces[:, 2]] - points[faces[:, 0]]
    return np.stack([np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e1, e2),
                     np.einsum("ij,ij->i", e2, e2)], axis=1)


def principal_stretches(ref_body: np.ndarray, fit_body: np.ndarray, faces: np.ndarray):
    """(smallest (T,), largest (T,)) principal stretch of every triangle
    (T, 3) from ref_body to fit_body (N, 3): the extremes of the length ratio
    of a segment in the triangle over all its directions (the singular
    values of the in-plane deformation); its three edges' ratios lie in
    between. Degenerate reference triangles get (1, 1)."""
    a, b, c = triangle_grams(np.asarray(ref_body, dtype=np.float64), faces).T
    d, e, f = triangle_grams(np.asarray(fit_body, dtype=np.float64), faces).T
    det = a * c - b * b
    ok = det > 1e-12 * np.maximum(a * c, 1e-300)
    det = np.where(ok, det, 1.0)
    # eigenvalues of G_ref^-1 G_fit (2 x 2): the squared principal stretches
    tr = (c * d - 2 * b * e + a * f) / det
    dt = (d * f - e * e) / det
    disc = np.sqrt(np.maximum(0.25 * tr * tr - dt, 0.0))
    hi = np.sqrt(np.maximum(0.5 * tr + disc, 0.0))
    lo = np.sqrt(np.maximum(0.5 * tr - disc, 0.0))
    return np.where(ok, lo, 1.0), np.where(ok, hi, 1.0)


def local_triangles(body_points: np.ndarray, body_faces: np.ndarray, points: np.ndarray, foot_triangle: np.ndarray,
                    k: int = 5) -> np.ndarray:
    """(M, k + 1) the body triangles an item vertex's local stretch is taken
    over: its closest triangle ``foot_triangle`` (M,) and the ``k`` whose
    centroids are nearest to it, on body_points (N, 3)."""
    kk = min(k, len(body_faces))
    _, near = cKDTree(np.asarray(body_points)[body_faces].mean(axis=1)).query(points, k=kk)
    near = np.asarray(near, dtype=np.int64).reshape(len(points), -1)
    return np.concatenate([np.asarray(foot_triangle, dtype=np.int64)[:, None], near], axis=1)


def vertex_stretch(triangles: np.ndarray, ref_body: np.ndarray, fit_body: np.ndarray, body_faces: np.ndarray):
    """(smallest (M,), largest (M,)) principal stretch (:func:`principal_stretches`)
    over the K body triangles (M, K) each item vertex is bound to."""
    tmin, tmax = principal_stretches(ref_body, fit_body, body_faces)
    return tmin[triangles].min(axis=1), tmax[triangles].max(axis=1)


def skin_range(e: np.ndarray, vertex_range: tuple):
    """(smallest (E,), largest (E,)) principal stretch over the 2K body
    triangles either end of each item edge e (E, 2) is bound to, from
    :func:`vertex_stretch`: the skin's own part of :func:`stretch_range`,
    which only widens it."""
    vmin, vmax = vertex_range
    return np.minimum(vmin[e[:, 0]], vmin[e[:, 1]]), np.maximum(vmax[e[:, 0]], vmax[e[:, 1]])


def stretch_range(ref_pts: np.ndarray, e: np.ndarray, triangles: np.ndarray, ref_body: np.ndarray,
                  fit_body: np.ndarray, body_faces: np.ndarray, tri: np.ndarray, bary: np.ndarray,
                  ref_clearance: np.ndarray, vertex_range: tuple | None = None):
    """The body's own local stretch range for item edges e (E, 2): (lo (E,),
    hi (E,)) edge-length ratios (new / reference), see :func:`metrics.shape_change`.

    ref_pts (M, 3) item on the reference, triangles (M, K) its bound body
    triangles, ref_body/fit_body (N, 3) with body_faces (T, 3), tri (M,) and
    bary (M, 3) each item vertex's closest reference skin point,
    ref_clearance (M,) its signed clearance (m); vertex_range: the result
    of :func:`vertex_stretch` if already computed."""
    if vertex_range is None:
        vertex_range = vertex_stretch(triangles, ref_body, fit_body, body_faces)
    smin, smax = skin_range(e, vertex_range)
    le_r = np.linalg.norm(ref_pts[e[:, 1]] - ref_pts[e[:, 0]], axis=1)
    fac = offset_factor(ref_body, fit_body, body_faces, tri, bary,
                        np.asarray(ref_clearance, dtype=np.float64), e, le_r)
    return np.minimum(smin, smin * fac), np.maximum(smax, smax * fac)
