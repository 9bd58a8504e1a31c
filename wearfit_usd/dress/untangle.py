"""Untangle: relax folded or over-stretched item patches towards the body's
local deformation.

Evaluating a binding keeps each item vertex at its offset above its bound
body triangles. Where that offset is larger than the body's local radius of
curvature (a ponytail far from a thin neck, a jacket over a muscular armpit)
the offset surface folds over itself: item triangles flip and edges shrink
or grow far more than the skin under them. Independent per-vertex
corrections (pushing penetrating vertices out to the body surface, lifting
an outer layer) do the same at a smaller scale.

The cure here is local: the item's *shape* should change like the body does
locally, i.e. every item edge ``r_j - r_i`` (reference) should become
``(r_j - r_i) @ G`` with ``G`` the body's local deformation gradient (3, 3),
row-vector convention, blended over the vertex's bound triangles with the
binding weights. On the vertices of bad elements and a few rings around
them, positions are found by a small sparse least-squares solve

    min  sum_edges w_e |x_j - x_i - g_ij|^2  +  eps sum_i w_i |x_i - p_i|^2

with all other vertices fixed where they are (a Poisson reconstruction of
the patch from the target edge vectors, glued to the unchanged rest).

The solve fits the blended body gradient, a field that is not integrable
where neighbouring vertices follow different body parts (the crotch seam
between a bent thigh and the other leg), and the constraints (out of the
body, over the inner layer) then move single vertices again. A last pass,
:func:`relax_edges`, therefore projects the few edges still outside the
body's own stretch range (:mod:`body_stretch`) back into it, one edge
length at a time (position-based, as in Mueller et al. 2007), under the
same constraints.

Units: those of the points (metres internally); gradients are unitless.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..geometry.sparse_solve import SPDSolver

FLIP_COS = 0.0     # a triangle is folded when its normal and the expected one make > 90 degrees
STRETCH_LO = 0.85  # edge length / expected edge length below this: over-compressed
STRETCH_HI = 1.2   # ... above this: over-stretched


def triangle_gradients(ref_body: np.ndarray, fit_body: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Deformation gradient (T, 3, 3) of every body triangle, row-vector
    convention: a vector ``v`` near triangle t on the reference becomes
    ``v @ G[t]`` on the fitted body. Built from the frames
    ``[e1; e2; unit normal]`` (edges in metres), so offsets along the normal
    keep their length (as in the binding). Degenerate triangles get the
    identity."""
    def frame(p):
        v0 = p[faces[:, 0]]
        e1 = p[faces[:, 1]] - v0
        e2 = p[faces[:, 2]] - v0
        n = np.cross(e1, e2)
        ln = np.linalg.norm(n, axis=1)
        n = n / np.where(ln < 1e-300, 1.0, ln)[:, None]
        return np.stack([e1, e2, n], axis=1), ln

    er, lr = frame(np.asarray(ref_body, dtype=np.float64))
    ef, _ = frame(np.asarray(fit_body, dtype=np.float64))
    ok = lr > 1e-10 * max(float(np.median(lr)), 1e-300)
    g = np.tile(np.eye(3), (len(faces), 1, 1))
    g[ok] = np.linalg.solve(er[ok], ef[ok])
    return g


def vertex_gradients(tri_grad: np.ndarray, triangles: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(M, 3, 3) gradient per item vertex: the binding-weighted blend of the
    gradients (T, 3, 3) of its bound triangles (M, k) with weights (M, k)."""
    return np.einsum("mk,mkij->mij", weights, tri_grad[triangles])


def edge_targets(ref_pts: np.ndarray, grad: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(E, 3) expected edge vectors ``(r_j - r_i) @ (G_i + G_j) / 2`` for
    edges (E, 2) of reference points (M, 3) and vertex gradients (M, 3, 3)."""
    d = ref_pts[edges[:, 1]] - ref_pts[edges[:, 0]]
    return 0.5 * np.einsum("ei,eij->ej", d, grad[edges[:, 0]] + grad[edges[:, 1]])


def expected_normals(ref_pts: np.ndarray, faces: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """(F, 3) normals (not unit) of the expected shapes of item triangles
    (F, 3): reference corners (M, 3) mapped by the mean vertex gradient
    (M, 3, 3) of the corners; zero for degenerate reference triangles."""
    gf = grad[faces].mean(axis=1)
    r0 = ref_pts[faces[:, 0]]
    a = np.einsum("fi,fij->fj", ref_pts[faces[:, 1]] - r0, gf)
    b = np.einsum("fi,fij->fj", ref_pts[faces[:, 2]] - r0, gf)
    n_exp = np.cross(a, b)
    ref_area = np.linalg.norm(np.cross(ref_pts[faces[:, 1]] - r0, ref_pts[faces[:, 2]] - r0), axis=1)
    n_exp[ref_area <= 1e-12] = 0.0
    return n_exp


def folded_triangles(n_exp: np.ndarray, pts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) bool: triangles (F, 3) of points (M, 3) whose normal opposes
    their expected normal n_exp (F, 3) (:func:`expected_normals`)."""
    p0 = pts[faces[:, 0]]
    n_new = np.cross(pts[faces[:, 1]] - p0, pts[faces[:, 2]] - p0)
    return np.einsum("fi,fi->f", n_exp, n_new) < 0


def lift_folds(ref_pts: np.ndarray, before: np.ndarray, after: np.ndarray, faces: np.ndarray,
               grad: np.ndarray, changed: np.ndarray, rounds: int = 12, slope: float = 0.5):
    """Undo the folds a per-vertex correction made, by moving folded patches
    as a whole.

    ``after`` (M, 3) is ``before`` (M, 3) with the ``changed`` (M,) vertices
    moved one by one (pushed out of the body, lifted over an inner layer).
    Neighbouring vertices get different pushes (their own depth, their own
    closest skin point and normal): where that difference exceeds the
    height of a triangle (a sliver hair card standing off the skin, a
    crease of a tight suit pushed from deep inside onto a concave crotch)
    the triangle folds. Every connected group of triangles that is folded
    in ``after`` but not in ``before`` is instead lifted from ``before``
    along one direction ``u`` (the mean of its vertices' corrections): each
    vertex by the envelope ``max_j (c_j - slope |r_i - r_j|)`` of the
    corrections ``c_j`` along ``u`` (so at least its own, and it falls off
    by at most ``slope`` per metre); a group that still folds moves by one
    translation (the largest ``c_j``), which cannot turn a triangle over.
    Groups that fold their neighbours in turn absorb them, for up to
    ``rounds`` rounds (a trouser hem lifted over a shoe collar on a posed
    ankle needs about 10); a group whose lift still folds a triangle at its
    rim keeps the per-vertex corrections.
    Returns (points (M, 3), vertices moved by a lift (M,) bool).
    """
    out = after.copy()
    lifted = np.zeros(len(after), dtype=bool)
    near = np.zeros(len(after), dtype=bool)  # corners of triangles touching changed vertices
    near[faces[changed[faces].any(axis=1)].ravel()] = True
    cand = faces[near[faces].any(axis=1)]   # every triangle a lift can turn
    if len(cand) == 0:
        return out, lifted
    n_exp = expected_normals(ref_pts, cand, grad)
    ok = ~folded_triangles(n_exp, before, cand)
    group = folded_triangles(n_exp, after, cand) & ok
    if not group.any():
        return out, lifted
    for r in range(rounds):
        gf = cand[group]
        verts, local = np.unique(gf, return_inverse=True)
        local = local.reshape(-1, 3)
        i = np.concatenate([local[:, 0], local[:, 1]])
        j = np.concatenate([local[:, 1], local[:, 2]])
        graph = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(len(verts), len(verts)))
        nc, lab = connected_components(graph, directed=False)
        d = after[verts] - before[verts]
        u = np.zeros((nc, 3))
        np.add.at(u, lab, d)
        un = np.linalg.norm(u, axis=1)
        u /= np.where(un > 0, un, 1.0)[:, None]
        along = np.einsum("vi,vi->v", d, u[lab])
        mag = np.zeros(len(verts))
        for g in range(nc):  # lift envelope: at least each vertex's own push, less slope x distance
            v = np.flatnonzero(lab == g)
            dist = np.linalg.norm(before[verts[v]][:, None] - before[verts[v]][None], axis=2)
            mag[v] = (along[v][None, :] - slope * dist).max(axis=1)
        comp = np.full(len(after), -1)
        comp[verts] = lab
        out = after.copy()
        out[verts] = before[verts] + mag[:, None] * u[lab]
        still = comp[cand[folded_triangles(n_exp, out, cand) & ok]]
        steep = np.isin(lab, still[still >= 0])  # the slope still folds: one translation
        top = np.zeros(nc)
        np.maximum.at(top, lab, along)
        mag[steep] = top[lab[steep]]
        out[verts] = before[verts] + mag[:, None] * u[lab]
        new = folded_triangles(n_exp, out, cand) & ok & ~group
        if not new.any() or r == rounds - 1:
            break
        group |= new  # the lift folded triangles at a group's rim: lift them with it
    # a group whose lift still folds its rim keeps the per-vertex corrections
    rim = comp[cand[new]]
    bad = np.unique(rim[rim >= 0])
    keep = ~np.isin(lab, bad)
    out[verts[~keep]] = after[verts[~keep]]
    lifted[verts[keep]] = True
    return out, lifted


def bad_elements(ref_pts: np.ndarray, pts: np.ndarray, faces: np.ndarray, edges: np.ndarray,
                 grad: np.ndarray, lo: float = STRETCH_LO, hi: float = STRETCH_HI):
    """Folded triangles and badly stretched edges.

    ref_pts/pts (M, 3) item before/after, faces (F, 3), edges (E, 2),
    grad (M, 3, 3) vertex gradients. A triangle is folded when its normal
    opposes the normal of its expected shape (reference corners mapped by the
    mean gradient of its corners); an edge is bad when its length leaves
    [lo, hi] x its expected length (:func:`edge_targets`).
    Returns (folded (F,) bool, bad edges (E,) bool).
    """
    return BadElements(ref_pts, faces, edges, grad, lo, hi)(pts)


class BadElements:
    """:func:`bad_elements` as a function of the points (M, 3) alone, for
    repeated checks of one item set under one gradient field: the expected
    normals and edge lengths (which do not depend on the current points) are
    computed once."""

    def __init__(self, ref_pts, faces, edges, grad, lo=STRETCH_LO, hi=STRETCH_HI):
        self.faces, self.edges, self.lo, self.hi = faces, edges, lo, hi
        self.n_exp = expected_normals(ref_pts, faces, grad)
        self.g = np.linalg.norm(edge_targets(ref_pts, grad, edges), axis=1)

    def __call__(self, pts):
        e = self.edges
        folded = folded_triangles(self.n_exp, pts, self.faces)
        ln = np.linalg.norm(pts[e[:, 1]] - pts[e[:, 0]], axis=1)
        ratio = ln / np.maximum(self.g, 1e-12)
        bad = ((ratio < self.lo) | (ratio > self.hi)) & (self.g > 1e-9)
        return folded, bad


def dilate(seed: np.ndarray, neighbours: sp.csr_matrix, rings: int) -> np.ndarray:
    """(M,) bool: ``seed`` grown by ``rings`` rings of the adjacency (M, M)."""
    out = np.asarray(seed, dtype=bool).copy()
    for _ in range(rings):
        out |= (neighbours @ out.astype(np.float64)) > 0
    return out


def gradient_operator(ref_pts: np.ndarray, faces: np.ndarray):
    """Per-triangle gradient of piecewise-linear functions on the reference
    item: (F, 3, 3) ``h[f, c]`` = gradient (1/m) of corner c's hat function,
    so that the gradient of a vertex field ``x`` over triangle f is
    ``sum_c h[f, c] (outer) x[faces[f, c]]``; plus unit normals (F, 3) and a
    validity mask (F,) (non-degenerate triangles)."""
    r = ref_pts[faces]
    n = np.cross(r[:, 1] - r[:, 0], r[:, 2] - r[:, 0])
    a2 = np.linalg.norm(n, axis=1)
    ok = a2 > 1e-12
    nh = n / np.where(ok, a2, 1.0)[:, None]
    opp = np.stack([r[:, 2] - r[:, 1], r[:, 0] - r[:, 2], r[:, 1] - r[:, 0]], axis=1)  # edge opposite corner c
    h = np.cross(nh[:, None, :], opp) / np.where(ok, a2, 1.0)[:, None, None]
    return h, nh, ok


class PatchSolver:
    """Re-solve the ``free`` vertices (M,) bool of an item so that every
    triangle touching them deforms like the body under it: the gradient of
    the map reference item -> new item over each triangle (its tangential
    part) is fitted to the mean body gradient ``grad`` (M, 3, 3) of its
    corners, every triangle weighted alike (deformation transfer, Sumner &
    Popovic 2004: a sliver triangle cannot flip cheaply, its gradient would
    change sign). The other vertices stay where they are in ``pts`` (M, 3).

    Each free vertex is tied to its position in ``pts`` with ``eps`` times
    its diagonal (keeps parts that are free as a whole in place). Assembled
    once; :meth:`solve` adds anchors (vertices pulled strongly towards given
    positions) and runs three sparse solves (x, y, z) on one sparse
    Cholesky factorisation (:class:`sparse_solve.SPDSolver`; the symbolic
    analysis is shared by the solves of one patch).
    """

    def __init__(self, ref_pts: np.ndarray, pts: np.ndarray, faces: np.ndarray, grad: np.ndarray,
                 free: np.ndarray, eps: float = 1e-2):
        self.idx = np.flatnonzero(free)
        self.pts = np.array(pts, dtype=np.float64, copy=True)
        m = len(pts)
        self.pos = np.full(m, -1)
        self.pos[self.idx] = np.arange(len(self.idx))
        f = faces[free[faces].any(axis=1)]
        h, nh, ok = gradient_operator(ref_pts, f)
        f, h, nh = f[ok], h[ok], nh[ok]
        jt = grad[f].mean(axis=1)                                      # (F, 3, 3)
        target = jt - np.einsum("fa,fb,fbc->fac", nh, nh, jt)          # tangential part P J
        nf = len(f)
        rows = np.broadcast_to((3 * np.arange(nf))[:, None, None] + np.arange(3)[None, None, :], (nf, 3, 3))
        cols = np.broadcast_to(f[:, :, None], (nf, 3, 3))
        g = sp.csr_matrix((h.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * nf, m))
        fixed = np.flatnonzero(~free)
        b = target.reshape(3 * nf, 3) - g[:, fixed] @ self.pts[fixed]
        gf = g[:, self.idx]
        gt = gf.T.tocsr()
        self.a = (gt @ gf).tocsr()
        self.diag = self.a.diagonal()
        self.rhs = gt @ b + (eps * self.diag)[:, None] * self.pts[self.idx]
        self.anchor = eps * self.diag
        self.spd = SPDSolver()

    def solve(self, anchor_idx: np.ndarray | None = None, anchor_pts: np.ndarray | None = None,
              weight: float = 10.0) -> np.ndarray:
        """New points (M, 3); anchor_idx (C,) vertices (non-free ones are
        ignored) pulled towards anchor_pts (C, 3) with ``weight`` x their
        diagonal."""
        out = self.pts.copy()
        if len(self.idx) == 0:
            return out
        anchor, rhs = self.anchor.copy(), self.rhs.copy()
        if anchor_idx is not None and len(anchor_idx):
            k = self.pos[anchor_idx] >= 0
            c = self.pos[anchor_idx[k]]
            extra = weight * self.diag[c]
            anchor[c] += extra
            rhs[c] += extra[:, None] * anchor_pts[k]
        self.spd.factor(self.a + sp.diags(anchor))  # same pattern each time: one symbolic analysis
        out[self.idx] = self.spd.solve(np.ascontiguousarray(rhs))
        return out


def untangle(ref_pts: np.ndarray, pts: np.ndarray, faces: np.ndarray, edges: np.ndarray,
             neighbours: sp.csr_matrix, grad: np.ndarray, constrain, iterations: int = 2,
             rings: int = 2, inner: int = 2, eps: float = 1e-2, anchor_weight: float = 10.0, detect=None):
    """Relax the neighbourhoods of folded triangles and badly stretched edges
    (:func:`bad_elements`) towards the body's local deformation
    (:class:`PatchSolver`), keeping the item out of the body and its layers
    in order.

    ref_pts/pts (M, 3) item points on the reference / after redress, faces
    (F, 3) and edges (E, 2) of all items (stacked indices), neighbours (M, M)
    item adjacency, grad (M, 3, 3) vertex gradients (:func:`vertex_gradients`).
    constrain(points (M, 3), mask (M,) bool, before (M, 3)) -> (points, moved (M,) bool):
        the hard constraints (push-out of the body, layer order) applied to
        the masked vertices; ``before`` are the points the solve started
        from (which met the constraints). A relaxed vertex it moves is anchored at its
        corrected position for the following solves, so the patch settles
        around it instead of folding against it.
    detect: :class:`BadElements` of these arguments, if already built.
    Each of ``iterations`` rounds re-detects bad elements, frees them plus
    ``rings`` rings and solves up to ``inner`` times while the constraints
    keep moving vertices; the result of the last ``constrain`` is kept.
    Returns (points (M, 3), touched (M,) bool: every vertex re-solved,
    stats dict: bad element counts before/after, number of solves).
    """
    pts = np.array(pts, dtype=np.float64, copy=True)
    touched = np.zeros(len(pts), dtype=bool)
    stats = {"solves": 0}
    anchored = np.zeros(len(pts), dtype=bool)
    anchor_pos = pts.copy()
    if detect is None:
        detect = BadElements(ref_pts, faces, edges, grad)
    for it in range(iterations):
        folded, bad = detect(pts)
        if it == 0:
            stats["folded_before"], stats["bad_edges_before"] = int(folded.sum()), int(bad.sum())
        seed = np.zeros(len(pts), dtype=bool)
        seed[faces[folded].ravel()] = True
        seed[edges[bad].ravel()] = True
        if not seed.any():
            break
        free = dilate(seed, neighbours, rings)
        touched |= free
        solver = PatchSolver(ref_pts, pts, faces, grad, free, eps=eps)
        for _ in range(inner):
            av = np.flatnonzero(anchored)
            new = solver.solve(av, anchor_pos[av], anchor_weight)
            stats["solves"] += 1
            fixed, moved = constrain(new, free, solver.pts)
            if not moved.any():
                break
            anchored |= moved
            anchor_pos[moved] = fixed[moved]
        pts = fixed
    folded, bad = detect(pts)
    stats["folded_after"], stats["bad_edges_after"] = int(folded.sum()), int(bad.sum())
    return pts, touched, stats


RELAX_BAND = (0.85, 1.2)   # relax_edges projects an edge into this band x the body's stretch range
RELAX_STOP = (0.82, 1.22)  # ... and works on every edge outside this one (the metric's is 0.8, 1.25)


def outside_range(ref_pts: np.ndarray, pts: np.ndarray, edges: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  fixed: np.ndarray, stop=None) -> np.ndarray:
    """(E,) bool: edges (E, 2) whose length ratio (pts over ref_pts, both
    (M, 3)) leaves ``stop`` (default :data:`RELAX_STOP`) x [lo, hi] (E,),
    leaving out degenerate edges and edges with both ends ``fixed`` (M,)."""
    stop = RELAX_STOP if stop is None else stop
    lr = np.linalg.norm(ref_pts[edges[:, 1]] - ref_pts[edges[:, 0]], axis=1)
    ln = np.linalg.norm(pts[edges[:, 1]] - pts[edges[:, 0]], axis=1)
    ok = (lr > 1e-9) & ~(fixed[edges[:, 0]] & fixed[edges[:, 1]])
    return ok & ((ln < stop[0] * lo * lr) | (ln > stop[1] * hi * lr))


def relax_edges(ref_pts: np.ndarray, pts: np.ndarray, edges: np.ndarray, limits,
                neighbours: sp.csr_matrix, fixed: np.ndarray, constrain, faces: np.ndarray, folded,
                candidates=None,
                iterations: int = 30, rings: int = 2, band=RELAX_BAND, stop=RELAX_STOP):
    """Bring item edges back into the body's local stretch range.

    ref_pts/pts (M, 3) item points on the reference / now, edges (E, 2),
    limits(idx (e,)) -> (lo (e,), hi (e,)): the body's stretch range of
    edges ``edges[idx]`` (length ratios new / reference,
    :func:`body_stretch.stretch_range`), neighbours (M, M) item adjacency,
    fixed (M,) bool vertices that must not move (rigid parts).
    constrain(points, mask, before) -> (points, moved): as in
    :func:`untangle`; folded(points) -> (F,) bool: which item triangles
    faces (F, 3) are folded.
    candidates: indices of the only edges that can be outside the range
    (default: all).

    Edges with a length ratio outside ``stop`` x [lo, hi] seed a region
    (plus ``rings`` rings, fixed vertices excluded). Each iteration moves
    both ends of every region edge outside ``band`` x [lo, hi] along the
    edge to the nearest length inside it (half each; all of it on a
    region vertex whose partner is outside the region), averages the moves
    per vertex (Jacobi), and applies ``constrain`` to the region. Stops when
    no region edge is outside ``stop``, or after ``iterations``. Each
    connected part of the region in which the pass folded a triangle gets
    its input positions back.

    Returns (points (M, 3), touched (M,) bool, stats dict).
    """
    pts = np.array(pts, dtype=np.float64, copy=True)
    touched = np.zeros(len(pts), dtype=bool)
    cand = np.arange(len(edges)) if candidates is None else np.asarray(candidates)
    bad = cand[outside_range(ref_pts, pts, edges[cand], *limits(cand), fixed, stop)]
    stats = {"relax_edges_before": len(bad), "relax_iterations": 0}
    if not len(bad):
        stats["relax_edges_after"] = 0
        return pts, touched, stats
    seed = np.zeros(len(pts), dtype=bool)
    seed[edges[bad].ravel()] = True
    region = dilate(seed, neighbours, rings) & ~fixed
    stats["relax_region"] = int(region.sum())
    lr = np.linalg.norm(ref_pts[edges[:, 1]] - ref_pts[edges[:, 0]], axis=1)
    act = np.flatnonzero((region[edges[:, 0]] | region[edges[:, 1]]) & (lr > 1e-9))
    e, lr = edges[act], lr[act]
    lo, hi = limits(act)
    lo_b, hi_b = band[0] * lo * lr, band[1] * hi * lr
    w = region.astype(np.float64)
    wa, wb = w[e[:, 0]], w[e[:, 1]]
    share_a = wa / np.maximum(wa + wb, 1e-300)
    start = pts
    for it in range(iterations):
        if not outside_range(ref_pts, pts, e, lo, hi, fixed, stop).any():
            break
        d = pts[e[:, 1]] - pts[e[:, 0]]
        ln = np.linalg.norm(d, axis=1)
        excess = ln - np.clip(ln, lo_b, hi_b)   # > 0: too long, < 0: too short
        on = excess != 0.0
        c = (excess / np.maximum(ln, 1e-300))[:, None] * d
        step = np.zeros_like(pts)
        np.add.at(step, e[:, 0], c * share_a[:, None])
        np.add.at(step, e[:, 1], -c * (1.0 - share_a)[:, None])
        count = np.bincount(e[:, 0], weights=on * wa, minlength=len(pts)) + \
            np.bincount(e[:, 1], weights=on * wb, minlength=len(pts))
        new = pts + step / np.maximum(count, 1.0)[:, None]
        pts, _ = constrain(new, region, pts)
        stats["relax_iterations"] = it + 1
    # a part of the region whose triangles this pass folded gets its input back
    new_folds = folded(pts) & ~folded(start)
    touched = region.copy()
    if new_folds.any():
        keep = sp.diags(region.astype(np.float64))
        part = connected_components(keep @ neighbours @ keep, directed=False)[1]
        back = np.isin(part, np.unique(part[faces[new_folds].ravel()])) & region
        pts[back] = start[back]
        touched &= ~back
        stats["relax_reverted_vertices"] = int(back.sum())
    stats["relax_edges_after"] = int(outside_range(ref_pts, pts, e, lo, hi, fixed, stop).sum())
    return pts, touched, stats
