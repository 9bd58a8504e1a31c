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
from scipy.sparse.csgraph import connected_components

from ..geometry.closest import SurfaceQuery
from ..geometry.mesh import short_edge_weights
from ..geometry.sparse_solve import SPDSolver
from ..kernels import assign_rows, similarity_place
from .rigid_parts import RigidParts

LOOSE_START = 0.01   # m: vertices farther than this from the body start to be smoothed
LOOSE_FULL = 0.04    # m: fully smoothed from here on
LOOSE_ITERATIONS = 40  # diffusion time, in half-steps of neighbour averaging
PATCH_MIN = 8  # vertices a loose patch (with its tight neighbours) needs for a frame of its own


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

    The displacement is taken in the frame of the body under each loose
    patch (``bound``): each connected loose patch, with its tight
    neighbours, is first moved by the best-fit rigid motion (Kabsch) of the
    body vertices it is bound to, from the plan's reference body to this
    one, ``S``; ``points - S(ref_points)`` is diffused and ``S`` added back.
    Neighbour averaging keeps a constant displacement but not a rotation's:
    averaging ``(R - I) p`` over a vertex's neighbours gives ``(R - I) p̄``,
    off by ``(R - I)(p̄ - p)``. A ponytail turned with the head had its
    strands, 0.3-1 mm apart and unevenly meshed, pulled millimetres apart
    (edges 4.4x their length at p99 in a walk's first frame), a long skirt
    turned with the hips in a dance stretched 3x. The frame comes from the
    body, not from a fit to the item's own displacement: on a body of another
    shape that fit found turns of 1-12 degrees in loose patches and took the
    long skirt 4 mm further from MakeHuman's own fit (p95 14.6 -> 18.8 mm on
    the thin body); the body under it does not turn. A tight vertex next to
    two patches is a boundary value of each, in each one's frame (with one
    value for both, one patch's frame applied to the other's boundary threw
    a walking suit's vertices up to 0.9 m).

    Solved in its symmetric form: on the loose vertices U (w > 0), multiplying
    a row by ``2 deg / w`` gives ``(diag(2 deg / w) + T L) d_U =
    diag(2 deg / w) d0_U - T L_UB d0_B`` with ``L = deg - adjacency`` the
    graph Laplacian and B their tight neighbours (fixed, d = d0). The matrix
    is symmetric positive definite: one sparse Cholesky, factorised once.

    Attributes (read by :class:`animate.frame_eval.FrameEvaluator`, which
    evaluates the same system with compiled loops):
    free: (U,) the loose vertices; boundary: (B,) their tight neighbours,
    once per loose patch each borders; ring: the loose vertices and their
    tight neighbours, sorted; mass: (U,) ``2 deg / w``;
    boundary_coupling: (U, B) sparse ``-T L_UB``; solver: the factorised
    :class:`SPDSolver` of ``diag(mass) + T L_UU``, None when no vertex is
    loose (:attr:`active` is then False and the smoother returns its input);
    patches: per loose patch with a frame, (item vertices (P,), the body
    vertices they are bound to (Q,), their summed binding weights (Q,)).

    ``bound``: the plan's :class:`binding.Binding` (the body vertices under
    each patch: :meth:`Binding.body_patch`); without it there are no
    patches and the displacement is taken from the reference as it is.

    ``points`` (M, 3), the item points the plan is built on: with them the
    averaging weighs a neighbour over a short edge more (:func:`geometry.mesh.short_edge_weights`:
    ``1 / length^2`` for edges under half their vertices' mean length, 1
    otherwise), ``walk = D^-1 W``, ``L = D - W`` with ``W`` the weighted
    adjacency and ``D`` its row sums; without them every neighbour weighs
    the same. A uniform average treats a 0.8 mm edge like a 20 mm one:
    where an item's mesh has a narrow strip of triangles (the crotch seam of
    a pair of hot pants), each side of the strip was pulled towards its own
    wide neighbours and the strip tore open, 0.8 mm to 6.6 mm in a walk's
    first frame (1.2 mm weighted). The weights' scale cancels (``mass``
    uses the same ``D``); a regular mesh is smoothed as before (the long
    skirt on the thin body: p95 15.9 mm from MakeHuman's helper either way;
    ``1 / length^2`` on every edge made it 17.1 mm, smoothing along the
    short edges of its quads).
    """

    def __init__(self, neighbours: sp.spmatrix, weight: np.ndarray,
                 time_steps: int = LOOSE_ITERATIONS, bound=None, points: np.ndarray | None = None):
        w = np.asarray(weight, dtype=np.float64)
        idx = np.flatnonzero(w > 0)
        self.free = self.boundary = self.ring = np.zeros(0, dtype=np.int64)
        self.mass = np.zeros(0)
        self.boundary_coupling = None
        self.solver = None
        self._ref_src = None
        self._frames_src = None
        self.patches = []  # [(item vertices (P,), body vertices (Q,), body weights (Q,))]
        if len(idx) == 0 or time_steps <= 0:
            return
        a = neighbours.tocsr().astype(np.float64)
        if points is None:
            a.data[:] = 1.0
        else:
            a = short_edge_weights(a, points)
        deg = np.asarray(a.sum(axis=1)).ravel()
        self.free = idx
        # the tight neighbours of loose vertices: boundary values (d = d0)
        nb = np.unique(a[idx].indices)
        tight = np.setdiff1d(nb, idx)
        self.ring = np.union1d(idx, tight)
        t = float(time_steps)
        lap_uu = sp.diags(deg[idx]) - a[idx][:, idx]
        coupling = (t * a[idx][:, tight]).tocoo()  # -T L_UB (L_UB = -adjacency)
        self.mass = 2.0 * np.where(deg[idx] > 0, deg[idx], 1.0) / w[idx]
        self.solver = SPDSolver()
        self.solver.factor((sp.diags(self.mass) + t * lap_uu).tocsc())
        # the connected loose patches; a tight vertex next to several is one
        # boundary value per patch (each in its patch's frame)
        if bound is None:
            n_patch, patch = 1, np.zeros(len(idx), dtype=np.int64)
        else:
            n_patch, patch = connected_components(a[idx][:, idx], directed=False)
            patch = patch.astype(np.int64)
        key = coupling.col.astype(np.int64) * n_patch + patch[coupling.row]
        keys, col = np.unique(key, return_inverse=True)
        self.boundary = tight[keys // n_patch]
        boundary_patch = keys % n_patch
        self.boundary_coupling = sp.csr_matrix((coupling.data, (coupling.row, col.ravel())),
                                               shape=(len(idx), len(keys)))
        self._free_frame = np.full(len(idx), -1, dtype=np.int64)
        self._boundary_frame = np.full(len(keys), -1, dtype=np.int64)
        if bound is None:
            return
        for c in range(n_patch):
            rows_u, rows_b = np.flatnonzero(patch == c), np.flatnonzero(boundary_patch == c)
            if len(rows_u) + len(rows_b) < PATCH_MIN:
                continue  # too small for a frame of its own: the reference's
            self._free_frame[rows_u] = len(self.patches)
            self._boundary_frame[rows_b] = len(self.patches)
            g = np.concatenate([idx[rows_u], self.boundary[rows_b]])
            self.patches.append((g, *bound.body_patch(g)))
        # vertices without a frame of their own take the identity, appended last
        self._free_frame[self._free_frame < 0] = len(self.patches)
        self._boundary_frame[self._boundary_frame < 0] = len(self.patches)

    def frame_reference(self, ref_points: np.ndarray, body_points: np.ndarray | None = None,
                        ref_body: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The reference the displacement is taken from: ``ref_points`` (M, 3)
        of the loose vertices (U, 3) and of their tight neighbours (B, 3,
        one per patch they border), each loose patch moved by the rigid
        motion of the body under it from ``ref_body`` to ``body_points``
        (N, 3) (the reference itself without bodies or patches). The arrays
        are reused by the next call."""
        if ref_points is not self._ref_src:  # per-frame calls pass the same reference
            self._ref_src = ref_points
            self._ref_u = np.take(ref_points, self.free, axis=0)
            self._ref_b = np.take(ref_points, self.boundary, axis=0)
            self._frames_src = None
        if body_points is None or ref_body is None or not self.patches:
            return self._ref_u, self._ref_b
        if self._frames_src is not ref_body:
            self._frames_src = ref_body
            ref = np.asarray(ref_points, dtype=np.float64)
            self._frames = RigidParts(self.patches, np.asarray(ref_body, dtype=np.float64), ref, scale=False)
            # the identity appended for the vertices without a frame of their own
            g = len(self.patches)
            self._rot = np.zeros((g + 1, 3, 3))
            self._shift = np.zeros((g + 1, 3))
            self._one = np.ones(g + 1)
            self._rot[-1] = np.eye(3)
            self._out_u, self._out_b = np.empty_like(self._ref_u), np.empty_like(self._ref_b)
            self._rows_u = np.arange(len(self._ref_u), dtype=np.int64)
            self._rows_b = np.arange(len(self._ref_b), dtype=np.int64)
        _, rot, shift = self._frames.transforms(np.ascontiguousarray(body_points, dtype=np.float64))
        self._rot[:-1], self._shift[:-1] = rot, shift
        # compiled: out[j] = ref[j] @ rot[frame j] + shift[frame j]
        similarity_place(self._ref_u, self._rows_u, self._free_frame, self._one, self._rot, self._shift, self._out_u)
        similarity_place(self._ref_b, self._rows_b, self._boundary_frame, self._one, self._rot, self._shift,
                         self._out_b)
        return self._out_u, self._out_b

    @property
    def active(self) -> bool:
        """Whether any vertex is smoothed (a factorised system exists)."""
        return self.solver is not None

    def __call__(self, points: np.ndarray, ref_points: np.ndarray, body_points: np.ndarray | None = None,
                 ref_body: np.ndarray | None = None) -> np.ndarray:
        """(M, 3) ``points`` with the displacement from ``ref_points`` (M, 3)
        diffused over the loose vertices (the input itself if none); with
        ``body_points`` and ``ref_body`` (N, 3) taken in the frames of the
        body under each loose patch (:meth:`frame_reference`)."""
        if self.solver is None:
            return points
        u, b = self.free, self.boundary
        ref_u, ref_b = self.frame_reference(ref_points, body_points, ref_body)
        # np.take and a row-record scatter: 2-3x faster than fancy indexing of (M, 3)
        rhs = self.mass[:, None] * (np.take(points, u, axis=0) - ref_u)
        if len(b):
            rhs += self.boundary_coupling @ (np.take(points, b, axis=0) - ref_b)
        out = np.array(points, dtype=np.float64, order="C", copy=True)
        return assign_rows(out, u, ref_u + self.solver.solve(rhs))


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
