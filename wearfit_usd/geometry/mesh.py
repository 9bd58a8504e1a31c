"""Mesh topology and shape helpers shared by every stage (plain numpy).

- :func:`adjacency`, :func:`components`, :func:`edges`: vertex adjacency,
  connected components and unique edges of a triangle mesh;
  :func:`boundary_loops`: the ordered open rims of a polygon mesh;
  :func:`edge_length_percentile`: how long its edges run;
- :func:`nondegenerate`: the one test for zero-area triangles;
- :func:`similarity_fit`: the one best-fit similarity (Umeyama 1991), with
  :func:`best_rotation` its rotation step (also used alone, uncentred).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from ..types import Faces, Mask, Matrix3, Points, Scalars

DEGENERATE_REL = 1e-12  # a triangle whose doubled area is below this x the mesh's median is degenerate
SHORT_EDGE_RATIO = 0.5  # edges shorter than this times their vertices' mean edge weigh more
EDGE_FLOOR = 1e-4  # m: shorter edges weigh as this long


def adjacency(faces: np.ndarray, n: int) -> sp.csr_matrix:
    """(n, n) symmetric 0/1 vertex adjacency of a triangle mesh."""
    f = np.asarray(faces, dtype=np.int64)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    a = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    a.data[:] = 1.0
    return a


def components(faces: np.ndarray, n: int) -> np.ndarray:
    """(n,) connected-component label of each vertex."""
    return connected_components(adjacency(faces, n), directed=False)[1]


def short_edge_weights(neighbours: sp.spmatrix, points: np.ndarray, ratio: float = SHORT_EDGE_RATIO,
                       floor: float = EDGE_FLOOR) -> sp.csr_matrix:
    """(M, M) the adjacency ``neighbours`` of a mesh weighted for averaging
    over it (the loose smoothing, the penetration guard's spread):
    entry ``(i, j)`` is ``max(1, (ratio * min(h_i, h_j) / max(l_ij, floor))^2)``
    with ``l_ij`` the edge's length and ``h_i`` the mean length of vertex
    i's edges; points (M, 3) in metres. Edges of a regular mesh weigh 1;
    an edge much shorter than its vertices' others (a narrow strip of
    triangles) weighs as ``1 / length^2`` against them."""
    a = sp.csr_matrix(neighbours, dtype=np.float64, copy=True)
    p = np.asarray(points, dtype=np.float64)
    if p.shape != (a.shape[0], 3):
        raise ValueError(f"points: expected ({a.shape[0]}, 3), got {p.shape}")
    rows = np.repeat(np.arange(a.shape[0]), np.diff(a.indptr))
    length = np.linalg.norm(p[a.indices] - p[rows], axis=1)
    h = np.bincount(rows, weights=length, minlength=a.shape[0]) / np.maximum(np.diff(a.indptr), 1)
    a.data = np.maximum(1.0, (ratio * np.minimum(h[rows], h[a.indices]) / np.maximum(length, floor)) ** 2)
    return a


def same_topology(points_a: Points, faces_a: Faces, points_b: Points, faces_b: Faces) -> bool:
    """Whether two meshes are one topology: as many points, the same triangles."""
    return (len(points_a) == len(points_b) and np.shape(faces_a) == np.shape(faces_b)
            and bool(np.array_equal(faces_a, faces_b)))


def edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) unique undirected edges."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    if len(e) == 0:
        return e.reshape(0, 2)
    e.sort(axis=1)
    n = int(e.max()) + 1
    key = np.unique(e[:, 0] * n + e[:, 1])  # 1-D keys: ~10x faster than unique(axis=0), same order
    return np.stack([key // n, key % n], axis=1)


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Ordered boundary loops of a polygon mesh, each walked along its faces'
    winding: edge ``a -> b`` of a face whose undirected edge no other face
    has (a hem, a neck opening); a loop starts at its smallest vertex, the
    loops in the order of those. A vertex where two loops touch is walked
    through once per loop.

    Parameters
    ----------
    faces : (F, k) int vertex indices (triangles, quads).

    Returns
    -------
    list of (L,) int64 vertex loops (at least 3 vertices each).
    """
    f = np.asarray(faces, dtype=np.int64)
    if f.size == 0:
        return []
    a = f.ravel()
    b = np.roll(f, -1, axis=1).ravel()
    n = int(f.max()) + 1
    key = np.minimum(a, b) * n + np.maximum(a, b)
    _, inv, count = np.unique(key, return_inverse=True, return_counts=True)
    open_ = count[inv.ravel()] == 1
    nxt: dict[int, list[int]] = {}
    for u, v in zip(a[open_].tolist(), b[open_].tolist()):
        nxt.setdefault(u, []).append(v)
    loops = []
    for start in sorted(nxt):
        while nxt.get(start):   # a vertex on two loops starts (or joins) both
            loop, v = [start], start
            while True:
                outs = nxt.get(v)
                if not outs:
                    break
                w = outs.pop(0)
                if w == start:
                    break
                loop.append(w)
                v = w
            if len(loop) >= 3:
                loops.append(np.asarray(loop, dtype=np.int64))
    return loops


def edge_length_percentile(points: Points, faces: Faces, q: float = 99.0) -> float:
    """The ``q``-th percentile of a mesh's (unique) edge lengths."""
    e = edges(faces)
    return float(np.percentile(np.linalg.norm(points[e[:, 1]] - points[e[:, 0]], axis=1), q))


def similarity_fit(src: Points, dst: Points, weights: Scalars | None = None,
                   scale: bool = True) -> tuple[float, Matrix3, NDArray[np.float64]]:
    """Best-fit similarity (Umeyama/Kabsch): dst ~ s * src @ rot + t.

    Parameters
    ----------
    src, dst : (P, 3) corresponding points.
    weights : (P,) non-negative weights (None: all equal).
    scale : fit the uniform scale ``s`` (False: ``s = 1``, a rigid fit).

    Returns
    -------
    s : float scale; rot : (3, 3) row-vector rotation (det +1); t : (3,)
    translation.
    """
    w = np.ones(len(src)) if weights is None else np.asarray(weights, float)
    w = w / w.sum()
    ms = w @ src
    md = w @ dst
    a = src - ms
    b = dst - md
    rot, sv = best_rotation((a * w[:, None]).T @ b)
    # np.sum, not einsum: einsum adds the three squares in another order
    s = float(sv.sum() / max(w @ np.sum(a * a, axis=1), 1e-300)) if scale else 1.0
    return s, rot, md - s * ms @ rot


def best_rotation(h: Matrix3) -> tuple[Matrix3, NDArray[np.float64]]:
    """The rotation step shared by every Kabsch/Umeyama fit.

    Parameters
    ----------
    h : (3, 3) weighted cross-covariance ``sum_i w_i a_i^T b_i`` of the
        (centred or not) source rows ``a`` and destination rows ``b``; or
        (n, 3, 3), n of them at once.

    Returns
    -------
    rot : (3, 3) (or (n, 3, 3)) row-vector rotation (det +1) minimising
        ``sum_i w_i |a_i @ rot - b_i|^2``; sv : (3,) (or (n, 3)) singular
        values of ``h``, the last one negated when a reflection was turned
        into a rotation (their sum over the source variance is the Umeyama
        scale).
    """
    u, sv, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(u @ vt))
    dm = np.ones(sv.shape)
    dm[..., 2] = d
    return (u * dm[..., None, :]) @ vt, sv * dm


def nondegenerate(points: Points, faces: Faces, rel: float = DEGENERATE_REL) -> Mask:
    """(T,) bool: triangles whose doubled area exceeds ``rel`` x the median
    doubled area of the mesh (zero-area and sliver triangles are False).

    points (N, 3), faces (T, 3) int.
    """
    p = np.asarray(points, dtype=np.float64)
    f = np.asarray(faces)
    a2 = np.linalg.norm(np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]), axis=1)
    if len(a2) == 0:
        return np.zeros(0, dtype=bool)
    return a2 > rel * max(float(np.median(a2)), 1e-300)
