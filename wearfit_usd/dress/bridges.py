"""Where an item bridges a fold of the body: bands its displacement is smoothed over.

A pair of hot pants spans the cleft between the buttocks: the vertices on
the left of the back seam are bound to the left wall of the cleft, those on
the right to the right wall, a few millimetres apart on the item and
centimetres apart on the body. Both walls are skin of one region, so no
region seam (:mod:`seams`) blends them; when a leg swings the walls turn
apart and the seam's edges, 2-3 mm long, opened to 16-25 mm in a walk's
first frame (5-6x the body's own stretch under them). The body does
not tear there: its surface runs down into the fold and back up, and its
skin weights change along that longer path.

:func:`bridge_weights` finds such places from the skin weights the binding
hands each item vertex: the joint weights of its bound triangles blended by
the binding's coefficients,

    omega_i = sum_k c_ik * (1/3) sum_{v in t_ik} w_v,

and the change of ``omega`` per metre along each item edge,
``g_e = |omega_i - omega_j|_1 / max(|e|, 1 mm)``. Edges with ``g_e`` above
``gradient`` follow different joints abruptly; the item vertices within
``band`` of them (along the item's edges) get a smoothing weight
``(1 - D / band)^2``, which the plan's :class:`corrections.LooseSmoother`
(length-weighted) uses to spread the difference over the band instead of
one edge. On MakeHuman's rig the body's own gradient reaches 170 per metre
at p99 (the fingers, where the skin's short edges turn one way or the
other); the bridging back seam of the hot pants has 80-117 per metre on
its 2-3 mm edges, the rest of that suit 40 at p99.

Arrays are numpy; lengths in metres.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from .item_weights import weight_matrix

BRIDGE_GRADIENT = 60.0  # joint-weight change (L1) per metre along an item edge that marks a bridge
BRIDGE_BAND = 0.03  # m along the item: half-width of the smoothing band around a bridge


def item_joint_weights(triangles: np.ndarray, coefficients: np.ndarray, body_faces: np.ndarray,
                       joint_indices: np.ndarray, joint_weights: np.ndarray, n_joints: int) -> sp.csr_matrix:
    """The skin weights a binding hands each item vertex (``omega``).

    Parameters
    ----------
    triangles : (M, K) int array
        Bound body triangles per item vertex (a :class:`binding.Binding`'s).
    coefficients : (M, K) float array
        Their blend weights (rows sum to 1; padding entries 0).
    body_faces : (T, 3) int array
    joint_indices, joint_weights : (N, I) arrays
        The body's skin influences.
    n_joints : int

    Returns
    -------
    (M, n_joints) sparse float matrix
        Rows sum to the blended weight sums (1 for normalised skins).
    """
    tri = np.asarray(triangles, dtype=np.int64)
    c = np.asarray(coefficients, dtype=np.float64)
    faces = np.asarray(body_faces, dtype=np.int64)
    ji, jw = np.asarray(joint_indices, dtype=np.int64), np.asarray(joint_weights, dtype=np.float64)
    if tri.shape != c.shape or tri.ndim != 2:
        raise ValueError(f"triangles {tri.shape} and coefficients {c.shape}: expected two (M, K) arrays")
    if ji.shape != jw.shape or ji.ndim != 2:
        raise ValueError(f"joint_indices {ji.shape} and joint_weights {jw.shape}: expected two (N, I) arrays")
    n, t, m = len(ji), len(faces), len(tri)
    skin = weight_matrix(ji, jw, int(n_joints))
    corners = sp.csr_matrix((np.full(3 * t, 1.0 / 3.0), (np.repeat(np.arange(t), 3), faces.ravel())), shape=(t, n))
    rows = sp.csr_matrix((c.ravel(), (np.repeat(np.arange(m), tri.shape[1]), tri.ravel())), shape=(m, t))
    return (rows @ (corners @ skin)).tocsr()


def bridge_weights(omega: sp.spmatrix, points: np.ndarray, item_edges: np.ndarray,
                   gradient: float = BRIDGE_GRADIENT, band: float = BRIDGE_BAND) -> np.ndarray:
    """Smoothing weight of the item vertices around bridges (see the module).

    Parameters
    ----------
    omega : (M, J) sparse float matrix
        :func:`item_joint_weights`.
    points : (M, 3) float array
        The item points the binding was made on.
    item_edges : (E, 2) int array
        The items' edges (stacked indices).
    gradient : float
        Per metre: edges whose ``g_e`` exceeds it are bridges.
    band : float
        m along the item.

    Returns
    -------
    (M,) float array
        0..1: 1 on the bridges' vertices, ``(1 - D / band)^2`` within
        ``band``, 0 elsewhere.
    """
    p = np.asarray(points, dtype=np.float64)
    e = np.asarray(item_edges, dtype=np.int64).reshape(-1, 2)
    m = len(p)
    omega = sp.csr_matrix(omega)
    if omega.shape[0] != m:
        raise ValueError(f"omega has {omega.shape[0]} rows for {m} item points")
    out = np.zeros(m)
    if len(e) == 0 or band <= 0:
        return out
    length = np.linalg.norm(p[e[:, 1]] - p[e[:, 0]], axis=1)
    change = np.asarray(abs(omega[e[:, 0]] - omega[e[:, 1]]).sum(axis=1)).ravel()
    bridge = change / np.maximum(length, 1e-3) > gradient
    if not bridge.any():
        return out
    seeds = np.unique(e[bridge].ravel())
    graph = sp.csr_matrix((np.r_[length, length], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(m, m))
    dist = dijkstra(graph, directed=False, indices=seeds, limit=band, min_only=True)
    near = np.isfinite(dist)
    out[near] = (1.0 - np.clip(dist[near] / band, 0.0, 1.0)) ** 2
    return out
