"""Per-vertex corrections of dressed items and how they spread over the item
mesh (plain numpy; lengths in metres).

- :func:`push_out` (with :func:`off_skin`): item vertices the target body
  swallowed go back out to the clearance they keep;
- :func:`spread_corrections`: single-vertex corrections (push-out, layers)
  spread smoothly over the item mesh so they do not stretch the edges at them;
- :func:`looseness`, :class:`LooseSmoother`: the displacement of parts hanging
  far from the body diffused over the item mesh (loose-part smoothing).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..geometry.closest import SurfaceQuery
from ..geometry.sparse_solve import SPDSolver
from ..kernels import assign_rows

LOOSE_START = 0.01   # m: vertices farther than this from the body start to be smoothed
LOOSE_FULL = 0.04    # m: fully smoothed from here on
LOOSE_ITERATIONS = 40  # diffusion time, in half-steps of neighbour averaging


def looseness(ref_clearance: np.ndarray, skirt_mask: np.ndarray | None = None) -> np.ndarray:
    """(M,) smoothing weight from the reference clearance: 0 up to
    LOOSE_START, 1 from LOOSE_FULL; skirt-like parts get 1 everywhere."""
    a = np.clip((np.asarray(ref_clearance) - LOOSE_START) / (LOOSE_FULL - LOOSE_START), 0.0, 1.0)
    if skirt_mask is not None:
        a = np.where(skirt_mask, 1.0, a)
    return a


def smoothstep(s: np.ndarray) -> np.ndarray:
    """(n,) ``3 s^2 - 2 s^3`` of s clipped to [0, 1]."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


class LooseSmoother:
    """Smooth the displacement ``points - ref_points`` (M, 3) over the item
    mesh where ``weight`` (M,) > 0; built once, applied per evaluation.

    Far from the body a vertex's local frames extrapolate: small differences
    between the frames of its K triangles become large, uneven displacements
    (a hem that tears or crumples). Diffusing the displacement over the mesh
    keeps the item's own shape; tight vertices (weight 0) are untouched.
    One implicit diffusion step ``(I - T A) d = d0`` with
    ``A = diag(w/2) (walk - I)`` (``walk`` = neighbour averaging, ``T`` the
    diffusion time): a linear map, so it can run every animation frame at
    the cost of one sparse solve.

    Solved in its symmetric form: on the loose vertices U (w > 0), multiplying
    a row by ``2 deg / w`` gives ``(diag(2 deg / w) + T L) d_U =
    diag(2 deg / w) d0_U - T L_UB d0_B`` with ``L = deg - adjacency`` the
    graph Laplacian and B their tight neighbours (fixed, d = d0). The matrix
    is symmetric positive definite: one sparse Cholesky, factorised once.

    Attributes (read by :class:`animate.frame_eval.FrameEvaluator`, which
    evaluates the same system with compiled loops):
    free: (U,) the loose vertices; boundary: (B,) their tight neighbours;
    ring: (U + B,) both, sorted; mass: (U,) ``2 deg / w``;
    boundary_coupling: (U, B) sparse ``-T L_UB``; solver: the factorised
    :class:`SPDSolver` of ``diag(mass) + T L_UU``, None when no vertex is
    loose (:attr:`active` is then False and the smoother returns its input).
    """

    def __init__(self, neighbours: sp.spmatrix, weight: np.ndarray,
                 time_steps: int = LOOSE_ITERATIONS):
        w = np.asarray(weight, dtype=np.float64)
        idx = np.flatnonzero(w > 0)
        self.free = self.boundary = self.ring = np.zeros(0, dtype=np.int64)
        self.mass = np.zeros(0)
        self.boundary_coupling = None
        self.solver = None
        self._ref_src = None
        if len(idx) == 0 or time_steps <= 0:
            return
        a = neighbours.tocsr().astype(np.float64)
        a.data[:] = 1.0
        deg = np.asarray(a.sum(axis=1)).ravel()
        self.free = idx
        # the tight neighbours of loose vertices: boundary values (d = d0)
        nb = np.unique(a[idx].indices)
        self.boundary = np.setdiff1d(nb, idx)
        self.ring = np.union1d(idx, self.boundary)
        t = float(time_steps)
        lap_uu = sp.diags(deg[idx]) - a[idx][:, idx]
        self.boundary_coupling = (t * a[idx][:, self.boundary]).tocsr()  # -T L_UB (L_UB = -adjacency)
        self.mass = 2.0 * np.maximum(deg[idx], 1.0) / w[idx]
        self.solver = SPDSolver()
        self.solver.factor((sp.diags(self.mass) + t * lap_uu).tocsc())

    @property
    def active(self) -> bool:
        """Whether any vertex is smoothed (a factorised system exists)."""
        return self.solver is not None

    def __call__(self, points: np.ndarray, ref_points: np.ndarray) -> np.ndarray:
        """(M, 3) ``points`` with the displacement from ``ref_points`` (M, 3)
        diffused over the loose vertices (the input itself if none)."""
        if self.solver is None:
            return points
        u, b = self.free, self.boundary
        if ref_points is not self._ref_src:  # per-frame calls pass the same reference
            self._ref_src = ref_points
            self._ref_u = np.take(ref_points, u, axis=0)
            self._ref_b = np.take(ref_points, b, axis=0)
        # np.take and a row-record scatter: 2-3x faster than fancy indexing of (M, 3)
        rhs = self.mass[:, None] * (np.take(points, u, axis=0) - self._ref_u)
        if len(b):
            rhs += self.boundary_coupling @ (np.take(points, b, axis=0) - self._ref_b)
        out = np.array(points, dtype=np.float64, order="C", copy=True)
        return assign_rows(out, u, self._ref_u + self.solver.solve(rhs))


def off_skin(res: dict, rows, clearance: np.ndarray) -> np.ndarray:
    """(R, 3) points at ``clearance`` (R,) m along the unit normal from the
    closest skin points of a :meth:`SurfaceQuery.closest` result ``res``,
    for its ``rows`` (bool mask or indices)."""
    n = res["normal"][rows]
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return res["point"][rows] + n * clearance[:, None]


def push_out(body_query: SurfaceQuery, item_points: np.ndarray, min_clearance: np.ndarray,
             mask: np.ndarray | None = None, neighbours: sp.spmatrix | None = None,
             smooth: float = 0.5, passes: int = 2):
    """Push item vertices that are inside the body back out.

    body_query: a :class:`SurfaceQuery` updated to the current body points.
    item_points: (M, 3). min_clearance: (M,) clearance (m) each vertex must be
        pushed out to if it is found inside; NaN or <= 0 = leave it (it was
        inside the reference body too).
    mask: (M,) bool, the vertices to test (default all): signed distances are
        only computed there.
    neighbours: (M, M) sparse adjacency of the item mesh(es); with it the
        moved vertices and their 1-ring get a light smoothing, and the ring
        follows part of its moved neighbours' displacement.
    Returns (points (M, 3), moved (M,) bool). Deterministic, so the same input
    gives the same output frame after frame.
    """
    pts = np.array(item_points, dtype=np.float64, copy=True)
    m = len(pts)
    target = np.nan_to_num(np.asarray(min_clearance, dtype=np.float64), nan=-1.0)
    test = np.ones(m, dtype=bool) if mask is None else np.asarray(mask, bool).copy()
    test &= target > 0
    moved = np.zeros(m, dtype=bool)
    for it in range(passes):
        idx = np.flatnonzero(test)
        if len(idx) == 0:
            break
        res = body_query.closest(pts[idx])
        inside = res["distance"] < 0
        if not inside.any():
            break
        sel = idx[inside]
        new = off_skin(res, inside, target[sel])
        delta = np.zeros_like(pts)
        delta[sel] = new - pts[sel]
        pts[sel] = new
        moved[sel] = True
        if neighbours is not None and it == 0 and smooth > 0:
            a = neighbours.tocsr()
            hit = np.zeros(m)
            hit[sel] = 1.0
            ring = (a @ hit > 0) & ~moved
            deg = np.asarray(a.sum(axis=1)).ravel()
            deg = np.maximum(deg, 1.0)
            # the 1-ring follows the mean displacement of its neighbours
            follow = (a @ delta) / deg[:, None]
            pts[ring] += smooth * follow[ring]
            # light Laplacian smoothing of moved + ring vertices
            zone = moved | ring
            avg = (a @ pts) / deg[:, None]
            pts[zone] += 0.5 * smooth * (avg[zone] - pts[zone])
            moved |= ring
            # smoothing may pull a few back in: test the zone again
            test = zone & (target > 0)
        else:
            test = np.zeros(m, dtype=bool)
            test[sel] = True
    return pts, moved


SPREAD_LENGTH = 0.08  # m: fade-out length of a per-vertex correction spread over the item mesh
SPREAD_RINGS = 8      # rings of neighbours around the corrected vertices that may follow
SPREAD_CLEARANCE_DRIFT = 0.001  # m: the spread may move an item's median vertex by at most this


def spread_corrections(ref_pts: np.ndarray, before: np.ndarray, after: np.ndarray, required: np.ndarray,
                       neighbours: sp.spmatrix, fixed: np.ndarray | None = None,
                       length: float = SPREAD_LENGTH, rings: int = SPREAD_RINGS,
                       rounds: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Spread per-vertex corrections smoothly over the item mesh.

    ``after`` (M, 3) is ``before`` (M, 3) with the ``required`` (M,) bool
    vertices moved one by one (pushed out of the body, lifted over an inner
    layer). Moving single vertices stretches or shortens every edge at them;
    here the correction field ``d = after - before`` is extended to the
    vertices within ``rings`` rings (never to ``fixed`` ones, e.g. rigid
    parts) by a screened harmonic extension on the reference item
    ``ref_pts`` (M, 3): on the free vertices ``D`` minimises

        sum_edges |D_i - D_j|^2 / l_ij^2  +  sum_i deg_i |D_i|^2 / length^2

    (``l_ij`` reference edge lengths: the first term is the strain the
    correction adds, the second lets it fade out over about ``length``),
    with ``D = d`` on the required vertices, ``D = 0`` beyond the rings.
    Every required vertex keeps at least its own correction: where the
    extension of its neighbours' corrections would carry it farther along
    its own (a small push next to a large one), it is released and follows
    the smooth field instead (an active set, ``rounds`` times).
    Returns (points (M, 3), vertices moved by the spread (M,) bool).
    """
    req = np.asarray(required, dtype=bool)
    out = np.array(after, dtype=np.float64, copy=True)
    spread = np.zeros(len(out), dtype=bool)
    if fixed is not None:
        req = req & ~fixed
    if not req.any():
        return out, spread
    a = neighbours.tocsr().astype(np.float64)
    a.data[:] = 1.0
    zone = req.copy()
    for _ in range(rings):
        zone |= (a @ zone.astype(np.float64)) > 0
    if fixed is not None:
        zone &= ~fixed
    zi = np.flatnonzero(zone)
    az = a[zi][:, zi].tocoo()
    lz = np.linalg.norm(ref_pts[zi[az.row]] - ref_pts[zi[az.col]], axis=1)
    w = sp.csr_matrix((1.0 / np.maximum(lz, 1e-6) ** 2, (az.row, az.col)), shape=(len(zi), len(zi)))
    deg = np.asarray(a[zi].sum(axis=1)).ravel()
    # vertices beyond the rings are fixed at D = 0: their edges only add to the diagonal
    wfull = np.asarray(w.sum(axis=1)).ravel()
    ar = a[zi].tocoo()
    lo = np.linalg.norm(ref_pts[zi[ar.row]] - ref_pts[ar.col], axis=1)
    outside = ~zone[ar.col]
    wout = np.bincount(ar.row[outside], weights=1.0 / np.maximum(lo[outside], 1e-6) ** 2, minlength=len(zi))
    lap = (sp.diags(wfull + wout + deg / length ** 2) - w).tocsr()
    d = (np.asarray(after, dtype=np.float64) - before)[zi]
    dn = np.linalg.norm(d, axis=1)
    u = d / np.maximum(dn, 1e-300)[:, None]
    req_z = req[zi]
    active = req_z.copy()
    for _ in range(rounds):
        f = np.flatnonzero(~active)
        c = np.flatnonzero(active)
        dz = np.zeros_like(d)
        dz[c] = d[c]
        if len(f):
            rhs = -(lap[f][:, c] @ d[c])
            solver = SPDSolver()
            solver.factor(lap[f][:, f].tocsc())
            dz[f] = solver.solve(np.ascontiguousarray(rhs))
        # the constraint D_c = d_c's multiplier along the correction: positive
        # = it holds the vertex back (the field would carry it farther out):
        # release it; a released vertex that falls short of its own
        # correction is held again
        mult = np.zeros(len(zi))
        mult[c] = -np.einsum("ij,ij->i", lap[c] @ dz, u[c])
        short = req_z & ~active & (np.einsum("ij,ij->i", dz, u) < dn - 1e-6)
        release = active & (mult > 1e-9 * np.maximum(lap.diagonal() * dn, 1e-300))
        if not release.any() and not short.any():
            break
        active = (active & ~release) | short
    short = req_z & (np.einsum("ij,ij->i", dz, u) < dn - 1e-6)
    dz[short] = d[short]
    out[zi] = before[zi] + dz
    spread[zi] = np.linalg.norm(dz - d, axis=1) > 1e-12
    return out, spread
