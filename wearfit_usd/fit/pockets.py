"""Pocket collapse: the last stage of the non-rigid body fit.

The reference body has pockets that a target may not have: the mouth bag,
the eye sockets (wider than the lid opening) and the gaps between toes and
fingers disappear when a body is voxel-remeshed (closed at the voxel size).
The registration's closest-point term rejects those vertices (their normals
disagree with the closed surface), so they stay where smoothness puts them,
centimetres under the target; pulling them straight onto their closest
points turns triangles over (the inner side of a lip faces backwards, its
closest point is on the front of the closed mouth).

This stage pulls them in anyway, in small orientation-preserving steps:

1. Region: vertices farther than ``min_distance`` from the target, grown by
   ``grow_rings`` vertex rings. Everything outside the region is held fixed,
   so each step solves only the region block of the registration's normal
   equations (the same smoothness + identity energy, one factorisation for
   the whole stage).
2. Each step pulls every region vertex a fraction ``step`` of the way to
   its closest target point (any normal: the pockets' walls must fold flat
   under the closed surface); the region moves by the displacement that
   follows these pulls under the registration's smoothness + identity
   energy (a displacement: a zero pull leaves the state exactly as it is).
3. Per-vertex line search: triangles that the step would turn over
   (normal turned by 90 degrees or more from the reference normal, the test of
   :func:`~wearfit_usd.fit.measures.count_flipped`) halve the step of their
   vertices and one ring around them, then the block is re-solved (only the
   right-hand side changes). After ``soft_rounds`` the vertices whose step
   reached zero are put back exactly where they were; if a step still
   flips a triangle after ``max_rounds`` it is dropped. So the stage never
   adds a flipped triangle: every accepted step is checked.

All arrays are in the registration's internal units (any length unit;
``min_distance`` in the same unit).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..geometry.closest import face_normals
from ..geometry.sparse_solve import SPDSolver


def vertex_adjacency(faces: np.ndarray, n_points: int) -> sp.csr_matrix:
    """(n_points, n_points) boolean-valued sparse adjacency of the mesh edges."""
    f = np.asarray(faces, dtype=np.int64)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    a = sp.csr_matrix((np.ones(len(i), dtype=np.float32), (i, j)), shape=(n_points, n_points))
    a.data[:] = 1.0
    return a


def _grow(mask: np.ndarray, adjacency: sp.csr_matrix, rings: int) -> np.ndarray:
    """``mask`` (N,) bool grown by ``rings`` vertex rings."""
    for _ in range(rings):
        mask = mask | (adjacency @ mask.astype(np.float32) > 0)
    return mask


def collapse_pockets(x: np.ndarray, n_points: int, faces: np.ndarray, ref_normals: np.ndarray,
                     L: sp.spmatrix, closest, *, weight: float,
                     min_distance: float, step: float = 0.7, iterations: int = 6,
                     grow_rings: int = 3, soft_rounds: int = 6, max_rounds: int = 30,
                     solver: str = "auto", adjacency: sp.csr_matrix | None = None):
    """Pull the vertices far from the target onto it without turning triangles over.

    x: (n, 3) current unknowns of the registration (the ``n_points`` mesh
    vertices first, then the per-triangle normal vertices). faces: (T, 3)
    the triangles behind the normal vertices (in their order). ref_normals:
    (T, 3) reference triangle normals (any length) for the flip test. L:
    (n, n) the registration's quadratic energy (smoothness + identity), PSD;
    each step moves the region by the displacement d minimising
    ``d^T L d + weight * sum |d_i - pull_i|^2`` (outside the region d = 0).
    closest: callable (M, 3) points -> ((M, 3) closest target points, (M,)
    distances). weight: pull weight per vertex (same scale as L).
    min_distance: vertices farther than this from the target start a
    region; keep it well above the chord error of the mesh (a fraction of
    its edge length), or convex parts are pulled in.

    Returns (x (n, 3) updated, region (n_points,) bool: the vertices this
    stage solved for, info dict: ``region`` vertex count, ``steps``
    accepted, ``solves``, ``held`` vertices whose last step was zero).
    """
    n = int(n_points)
    faces = np.asarray(faces, dtype=np.int64)
    info = {"region": 0, "steps": 0, "solves": 0, "held": 0}
    region = np.zeros(n, bool)
    if iterations <= 0:
        return x, region, info
    _, dist = closest(x[:n])
    far = dist > min_distance
    if not far.any():
        return x, region, info
    adjacency = vertex_adjacency(faces, n) if adjacency is None else adjacency
    region = _grow(far, adjacency, grow_rings)
    rv = np.flatnonzero(region)
    nr = len(rv)
    tri_in = np.flatnonzero(region[faces].any(axis=1))
    unknown = np.concatenate([rv, n + tri_in])  # region vertices, then their normal vertices
    Lr = sp.csr_matrix(L)[unknown]
    A = Lr[:, unknown] + sp.diags(np.concatenate([np.full(nr, float(weight)),
                                                  np.zeros(len(tri_in))]))
    blk = SPDSolver(solver)
    blk.factor(A)
    # only triangles with a region vertex can change
    tf = faces[tri_in]
    tn0 = ref_normals[tri_in]

    def flipped(pts):
        return np.einsum("ij,ij->i", tn0, face_normals(pts, tf, unit=False)) <= 0

    info["region"] = nr
    last = np.ones(nr)
    where = np.full(n, -1)  # vertex -> region row
    where[rv] = np.arange(nr)
    for _ in range(iterations):
        xo = x[:n]
        cp, _ = closest(xo[rv])
        move = step * (cp - xo[rv])  # (nr, 3) pull of this step
        was = flipped(xo)
        # per-vertex step length (line search), starting from twice the
        # last accepted one: vertices that were held are likely held again
        scale = np.minimum(1.0, np.maximum(2.0 * last, 0.125))
        accepted = None
        x_u = x[unknown]
        for r in range(max_rounds):
            # displacement form: a zero move keeps the current state exactly
            rhs = np.zeros_like(x_u)
            rhs[:nr] = weight * scale[:, None] * move
            sol = x_u + blk.solve(rhs)
            info["solves"] += 1
            xn = x.copy()
            xn[unknown] = sol
            if r >= soft_rounds:
                held = scale == 0
                xn[rv[held]] = xo[rv[held]]
            bad = flipped(xn[:n]) & ~was
            if not bad.any():
                accepted = xn
                break
            m = np.zeros(n, bool)
            m[tf[bad].ravel()] = True
            m = _grow(m, adjacency, 1)
            k = where[np.flatnonzero(m)]
            k = k[k >= 0]
            scale[k] *= 0.5
            scale[scale < 0.1] = 0.0
        if accepted is None:
            break
        x = accepted
        info["steps"] += 1
        info["held"] = int((scale == 0).sum())
        last = scale
    return x, region, info
