"""Compile (or load from numba's cache) every kernel ahead of the first
real call: :func:`warm_up`, run by ``python3 -m wearfit_usd.kernels`` (and
so by install.sh)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .binding import add_rows, binding_eval, binding_eval_rows, diffusion_rhs, similarity_place, similarity_transforms
from .closest import closest_candidates, closest_signed
from .cloth import ClothBody, ClothEdges, ClothParams, ClothSamples, ClothState, ClothTargets, ClothTethers, cloth_frame
from .grid import RadiusGrid
from .guard import GuardBody, GuardState, guard_estimate, guard_frame
from .jit import HAVE_NUMBA
from .layers import first_hits
from .normals import face_normal_sums, face_normals, vertex_normals
from .strain import StrainRest, edge_incidence, strain_frame, weld_groups


def warm_up() -> bool:
    """Run every kernel once on tiny inputs of the types the real callers
    pass (float64 points, int64 indices, scipy's int32 CSR indices), so the
    first real call does not pay the compilation. Returns whether numba is
    in use (without it there is nothing to compile)."""
    if not HAVE_NUMBA:
        return False
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    face_normals(pts, faces)
    vertex_normals(pts, faces)
    cand = np.array([[0, 1]] * 4, dtype=np.int64)
    closest_candidates(pts, cand, pts, faces)
    RadiusGrid(pts, 0.5).nearest(pts)
    # a closed tetrahedron for the signed kernels: its 6 edges, vertex rings
    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], dtype=np.int64)
    edge_id = np.array([[1, 3, 0], [0, 4, 2], [3, 5, 4], [2, 5, 1]], dtype=np.int64)
    edge_faces = np.array([[0, 1], [0, 3], [1, 3], [0, 2], [1, 2], [2, 3]], dtype=np.int64)
    ring = np.array([[0, 1, 3], [0, 1, 2], [0, 2, 3], [1, 2, 3]], dtype=np.int64)
    face_n = face_normals(pts, tet)
    edge_n = face_n[edge_faces].sum(axis=1)
    closest_signed(pts, np.array([[0, 1, 2, 3]] * 4, dtype=np.int64), pts, tet, face_n, edge_n, edge_id, ring)
    # the penetration guard, as animate.penetration_guard calls it
    vsum = np.empty((4, 3))
    face_normal_sums(tet, face_n, vsum)
    body = GuardBody(pts, tet, face_n, edge_id, edge_faces, ring, vsum)
    grid = RadiusGrid(pts, 0.03).arrays
    probe = np.array([[0.2, 0.2, 0.2], [0.0, 0.0, -0.1]])
    est, vi = np.empty(2), np.empty(2, dtype=np.int64)
    guard_estimate(probe, np.full(2, -1, dtype=np.int64), body, grid, 0.03 ** 2, est, vi)
    state = GuardState(np.array([[0, 1, 2, 3]] * 2, dtype=np.int64), np.zeros(2), np.ones(2, dtype=bool),
                       np.full(2, 0.001), np.zeros(2), np.zeros((2, 3)), np.full(2, -1, dtype=np.int64))
    guard_frame(probe, state, body, grid, 0.03 ** 2, 0.7, 0.001, 0.002, np.empty((2, 3)))
    # the binding and the per-frame plan evaluation (frame_eval.FrameEvaluator),
    # with the index dtypes they meet: int32 CSR indices, int64 vertex rows
    mat = sp.csr_matrix(np.ones((2, 6)))
    binding_eval(pts, faces, mat, np.zeros((6, 3)))
    out = np.zeros((2, 3))
    rows = np.arange(2, dtype=np.int64)
    binding_eval_rows(pts, faces, mat.indptr, mat.indices, mat.data, rows, np.zeros((6, 3)), out)
    similarity_place(pts[:2], rows, np.zeros(2, dtype=np.int64), np.ones(1), np.eye(3)[None], np.zeros((1, 3)), out)
    cov = sp.csr_matrix(np.ones((3, 4)))
    mean = sp.csr_matrix(np.full((1, 4), 0.25))
    similarity_transforms(pts, mean, cov, np.zeros((1, 3)), np.ones(1), True)
    lap = sp.csr_matrix(np.ones((2, 1)))
    diffusion_rhs(pts, rows, np.zeros(1, dtype=np.int64), out, out[:1], np.ones(2), lap.indptr, lap.indices,
                  lap.data, np.empty((2, 3)))
    add_rows(out, rows, out.copy(), out.copy())
    # the cloth frame (animate.cloth), on two free particles hanging from a
    # kinematic one over the tetrahedron's vertex graph
    x = np.array([[0.0, 2, 0], [0.0, 1.5, 0], [0.0, 1, 0]])
    ptr = np.array([0, 3, 6, 9, 12], dtype=np.int64)
    idx = np.array([1, 2, 3, 0, 2, 3, 0, 1, 3, 0, 1, 2], dtype=np.int64)
    unit = pts / np.maximum(np.linalg.norm(pts, axis=1, keepdims=True), 1e-12)
    cloth_frame(ClothState(x, np.zeros((2, 3)), np.array([1.0, 1.0, 0.0]), np.zeros(2)),
                ClothTargets(x.copy(), x.copy()),
                ClothEdges(np.array([[0, 1], [1, 2]], dtype=np.int64), np.array([0.5, 0.5]),
                           np.array([0, 1, 2], dtype=np.int64)),
                ClothTethers(np.array([2, 2], dtype=np.int64), np.array([1.0, 0.5])),
                ClothSamples(np.array([[0, 0], [1, 1]], dtype=np.int64), np.array([0, 1, 2], dtype=np.int64),
                             np.full(2, -1, dtype=np.int64), np.zeros(2), np.zeros(2),
                             np.array([0, -1], dtype=np.int64), np.zeros(2), np.zeros(2)),
                ClothBody(pts, pts, unit, unit, ptr, idx, idx.reshape(4, 3), np.zeros((1, 4)), 0.0, 0.0),
                ClothParams(np.array([0.0, -9.81, 0.0]), 1.0, 0.3, 0.0, 1e-6, 1 / 30, 2, 2))
    # the strain limit (animate.strain_limit): one item edge over the tetrahedron, torn
    e = np.array([[0, 1]], dtype=np.int64)
    local = np.zeros((2, 2), dtype=np.int64)
    rest = StrainRest(e, np.ones(1), local, tet, np.ones((4, 3)), np.zeros(2, dtype=np.int64), np.full((2, 3), 1 / 3),
                      np.zeros((2, 3)), unit[:2].copy(), np.zeros(2), *edge_incidence(e, 2),
                      *weld_groups(np.array([0, 1]), np.array([0, 0]), np.full(2, 0.5)))
    strain_frame(rest, pts, unit, np.array([[0.0, 0, 0], [3.0, 0, 0]]), np.ones(2), 1.1, 2, 0.001)
    # the layer pass's ray search (animate.layer_hold)
    first_hits(pts, faces, np.array([[0, 1], [1, -1]], dtype=np.int64), pts[:2] + 1.0, -unit[:2], np.ones(2))
    return True
