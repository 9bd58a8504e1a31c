"""The per-frame penetration guard's compiled kernels
(:class:`animate.penetration_guard.PenetrationGuard`): the clearance
estimate through the nearest body vertex, and one whole frame of the guard.

Their numpy twin is the guard's own numpy path (``compiled=False``), which
is built on :class:`geometry.closest.SurfaceQuery`: it stays in the guard's
module, as the kernels package cannot import geometry (geometry imports the
kernels). The tests run both paths frame after frame and compare them.

The kernels take the body, the item state and the radius grid as named
tuples of arrays (:class:`GuardBody`, :class:`GuardState`,
:class:`~.grid.GridArrays`). Lengths in the units of the points (metres).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .closest import closest_feature, closest_on_triangle, point_on
from .grid import nearest_from
from .jit import jit, prange
from .normals import vertex_pseudo_normal


class GuardBody(NamedTuple):
    """The body of one frame, as the guard kernels take it."""
    points: np.ndarray       # (N, 3) float64
    faces: np.ndarray        # (T, 3) int64
    face_normal: np.ndarray  # (T, 3) unit face normals
    edge_id: np.ndarray      # (T, 3) int64 edges 01, 12, 20 of each face
    edge_faces: np.ndarray   # (E, w) int64 the faces of each edge in index order, -1 padded
    ring: np.ndarray         # (N, w) int64 triangles around each vertex, padded by repeating the first
    normal_sums: np.ndarray  # (N, 3) per-vertex sums of the unit face normals (normals.face_normal_sums)


class GuardState(NamedTuple):
    """Per item vertex (M of them), what the guard keeps between frames:
    frame-0 facts (read only) and the push (updated every frame)."""
    cand0: np.ndarray      # (M, c) int64 nearest body triangles at frame 0
    approx0: np.ndarray    # (M,) clearance estimate at frame 0
    outside0: np.ndarray   # (M,) bool guarded: outside the body at frame 0
    target: np.ndarray     # (M,) clearance to restore
    push: np.ndarray       # (M,) current push amount (updated)
    direction: np.ndarray  # (M, 3) current push direction (updated)
    hint: np.ndarray       # (M,) int64 last frame's nearest body vertex, -1 none (updated)


@jit
def vertex_estimate(px, py, pz, bi, points, vsum):
    """Offset of (px, py, pz) along the unit normal sum vsum[bi] of body vertex bi."""
    nx = vsum[bi, 0]
    ny = vsum[bi, 1]
    nz = vsum[bi, 2]
    ln = max(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
    return ((px - points[bi, 0]) * nx + (py - points[bi, 1]) * ny + (pz - points[bi, 2]) * nz) / ln


@jit
def guard_estimate(q, hint, body, grid, r2, out_est, out_vi):
    """Clearance estimate of each q (M, 3) through its nearest body vertex
    within sqrt(r2) (search of ``grid``, a :class:`~.grid.GridArrays` over
    body.points, from ``hint`` (M,)): offset along that vertex's normal sum
    (``body``: :class:`GuardBody`), written to out_est (M,) (+inf when no
    vertex is that near) and that vertex to out_vi (M,) (0 when none)."""
    points, spts, order, starts, lo, h, dims = grid
    vsum = body.normal_sums
    for i in range(q.shape[0]):
        qx = q[i, 0]
        qy = q[i, 1]
        qz = q[i, 2]
        bi, _ = nearest_from(qx, qy, qz, hint[i], r2, points, spts, order, starts, lo, h, dims)
        if bi < 0:
            out_est[i] = np.inf
            out_vi[i] = 0
        else:
            out_est[i] = vertex_estimate(qx, qy, qz, bi, points, vsum)
            out_vi[i] = bi


@jit
def _exact_signed(ix, iy, iz, i, near, cand0, ring, points, faces, edge_id, face_n, edge_faces):
    """Signed distance of (ix, iy, iz) to the closest of the triangles
    cand0[i] and ring[near] (first wins ties), sign and normal (not unit)
    from the closest feature's pseudo-normal, as geometry.closest's SurfaceQuery
    (an edge's: the sum of its faces' unit normals, edge_faces (E, w) in
    index order, -1 padded)."""
    nc = cand0.shape[1]
    bd = np.inf
    bs = 0.0
    bt = 0.0
    bin_ = False
    btri = cand0[i, 0]
    for k in range(nc + ring.shape[1]):
        f = cand0[i, k] if k < nc else ring[near, k - nc]
        dist, s, t, inside = closest_on_triangle(ix, iy, iz, f, points, faces)
        if dist < bd:
            bd = dist
            bs = s
            bt = t
            bin_ = inside
            btri = f
    cx, cy, cz = point_on(btri, bs, bt, points, faces)
    e, v = closest_feature(btri, bs, bt, bin_, faces, edge_id)
    if e >= 0:
        nx = 0.0
        ny = 0.0
        nz = 0.0
        for k in range(edge_faces.shape[1]):
            f = edge_faces[e, k]
            if f < 0:
                break
            nx += face_n[f, 0]
            ny += face_n[f, 1]
            nz += face_n[f, 2]
    elif v >= 0:
        nx, ny, nz = vertex_pseudo_normal(v, points, faces, ring, face_n)
    else:
        nx = face_n[btri, 0]
        ny = face_n[btri, 1]
        nz = face_n[btri, 2]
    sd = np.sqrt(bd)
    if (ix - cx) * nx + (iy - cy) * ny + (iz - cz) * nz < 0:
        sd = -sd
    return sd, nx, ny, nz


@jit(parallel=True)
def guard_frame(item, state, body, grid, r2, decay, margin, drop, out):
    """One frame of :meth:`PenetrationGuard.apply` for all item vertices item
    (M, 3) (state: :class:`GuardState`, body: :class:`GuardBody`, grid: a
    :class:`~.grid.GridArrays` over body.points, searched within sqrt(r2)):
    decays the pushes by ``decay``, finds the suspects by the nearest-vertex
    estimate (state.hint: last frame's nearest vertex, updated), gives them
    the exact signed distance among their frame-0 triangles state.cand0 and
    the ring of the body vertex nearest to them, pushes them out to
    state.target, and checks the pushed point the same way: one still
    within ``margin`` of the surface (pushed into another body part, or a
    wrong first normal) gets a second push from there, the two combined
    into one displacement. A suspect: estimate ``drop`` under its frame-0
    value, or under ``margin``. Writes out (M, 3); returns the number of
    suspects inside by more than ``margin`` before correction. Runs on all
    cores (1.7x faster on 2 cores for the 12,661 vertices of ref_male's
    items; the same numbers as one thread)."""
    cand0, approx0, outside0, target, push, direction, hint = state
    points, faces, face_n, edge_id, edge_faces, ring, vsum = body
    _, spts, order, starts, lo, h, dims = grid  # grid.points is body.points
    n_inside = 0
    for i in prange(item.shape[0]):  # every i touches only row i of the state arrays
        p = push[i] * decay
        ix = item[i, 0]
        iy = item[i, 1]
        iz = item[i, 2]
        px = ix + p * direction[i, 0]
        py = iy + p * direction[i, 1]
        pz = iz + p * direction[i, 2]
        bi, _ = nearest_from(px, py, pz, hint[i], r2, points, spts, order, starts, lo, h, dims)
        hint[i] = bi
        if bi >= 0 and outside0[i]:
            est = vertex_estimate(px, py, pz, bi, points, vsum)
            if est < approx0[i] - drop or est < margin:
                # the body vertex nearest to the item vertex before any push
                near, _ = nearest_from(ix, iy, iz, bi, r2, points, spts, order, starts, lo, h, dims)
                if near < 0:
                    near = bi
                sd, nx, ny, nz = _exact_signed(ix, iy, iz, i, near, cand0, ring, points, faces, edge_id, face_n,
                                               edge_faces)
                ln = max(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-12)
                if sd < -margin:
                    n_inside += 1
                if sd < target[i] and target[i] - sd > p:
                    p = target[i] - sd
                direction[i, 0] = nx / ln
                direction[i, 1] = ny / ln
                direction[i, 2] = nz / ln
                if p >= 1e-5:
                    qx = ix + p * direction[i, 0]
                    qy = iy + p * direction[i, 1]
                    qz = iz + p * direction[i, 2]
                    near2, _ = nearest_from(qx, qy, qz, near, r2, points, spts, order, starts, lo, h, dims)
                    if near2 >= 0:
                        sd2, mx, my, mz = _exact_signed(qx, qy, qz, i, near2, cand0, ring, points, faces,
                                                        edge_id, face_n, edge_faces)
                        if sd2 < margin:
                            lm = max(np.sqrt(mx * mx + my * my + mz * mz), 1e-12)
                            extra = target[i] - sd2
                            dx = p * direction[i, 0] + extra * mx / lm
                            dy = p * direction[i, 1] + extra * my / lm
                            dz = p * direction[i, 2] + extra * mz / lm
                            p = np.sqrt(dx * dx + dy * dy + dz * dz)
                            if p > 0.0:
                                direction[i, 0] = dx / p
                                direction[i, 1] = dy / p
                                direction[i, 2] = dz / p
        if p < 1e-5:
            p = 0.0
        push[i] = p
        out[i, 0] = ix + p * direction[i, 0]
        out[i, 1] = iy + p * direction[i, 1]
        out[i, 2] = iz + p * direction[i, 2]
    return n_inside
