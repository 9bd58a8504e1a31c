"""Bind item vertices to a body surface ("fit metric"), evaluate as one sparse product.

Each item vertex ``p`` is bound to its ``k`` nearest body triangles, by the
distance from ``p`` to the triangle itself (not to its centroid: on a coarse
or unevenly meshed body the nearest centroids belong to small triangles
beside the vertex, or to large ones far across a joint). In triangle
``t = (v1, v2, v3)`` with unit normal ``n`` it is stored as the closest
point of the triangle to its projection, barycentric ``(a', b')``, plus the
rest in the triangle's orthonormal frame (``t1`` the unit bisector of the
edges at ``v1``, ``t2 = n x t1``) and the offset ``c`` along the normal:

    p = v1 + a' (v2 - v1) + b' (v3 - v1) + r1 t1 + r2 t2 + c n

(``r1 = r2 = 0`` where p lies over the triangle). The frame turns with the
triangle but does not stretch with it: a vertex beyond the triangle's edge
(a neighbour's, a skirt's hem hanging below the hips) keeps its distance
instead of being thrown by the triangle's own stretch times its distance in
triangle sizes (the plain affine frame ``v1 + a e1 + b e2`` extrapolates).
With the frame vertices ``v1 + n``, ``v1 + t1``, ``v1 + t2`` this is linear
in the stacked vector. The ``k`` triangles are blended with smooth
inverse-distance weights that reach 0 at the (k+1)-th candidate's distance
(so the binding is continuous over the item). Everything is one sparse
matrix ``W`` (M, N + 3T) acting on ``stacked = [body points (N, 3); normal
vertices (T, 3); tangent vertices (T, 3), (T, 3)]``.

On the body it was built on, ``W @ stacked`` reproduces the item exactly; a
rigid motion of the body moves the item rigidly; the offset along the unit
normal keeps the item's clearance when the body grows or shrinks.

Units: those of the points (metres internally).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..geometry.closest import closest_point_on_triangles
from ..kernels import binding_eval
from ..kernels.binding import frame_from_edges, tangent_frames_numpy


def triangle_frames(points: np.ndarray, faces: np.ndarray):
    """Edge vectors e1 = v2-v1, e2 = v3-v1 (T, 3) and unit normals (T, 3) plus
    the doubled areas (T,) of the triangles."""
    v1 = points[faces[:, 0]]
    e1 = points[faces[:, 1]] - v1
    e2 = points[faces[:, 2]] - v1
    n = np.cross(e1, e2)
    ln = np.linalg.norm(n, axis=1)
    return e1, e2, n / np.where(ln < 1e-300, 1.0, ln)[:, None], ln


@dataclass
class Binding:
    """A linear binding of M item vertices to a body with N vertices, T triangles.

    matrix: (M, N + 3T) CSR, item = matrix @ stacked(body_points).
    faces: (T, 3) body triangles.
    triangles: (M, k) bound triangle of each item vertex, nearest first.
    weights: (M, k) blend weights (rows sum to 1).
    local: (M, k, 3) local (a, b, c) coordinates; c = offset along the unit
        normal (the vertex's clearance above that triangle's plane).
    used: (U,) sorted indices of the triangles any vertex is bound to; only
        their normal vertices are computed by :meth:`evaluate`.
    rest: (M, N + 3T) CSR, the part of ``matrix`` that places each vertex
        beyond its triangles' closest points (the orthonormal-frame rest):
        ``rest @ stacked`` is that offset, (M, 3).
    """
    matrix: sp.csr_matrix
    faces: np.ndarray
    triangles: np.ndarray
    weights: np.ndarray
    local: np.ndarray
    used: np.ndarray
    rest: sp.csr_matrix | None = None

    def __post_init__(self):
        n_tri, n_used = len(self.faces), len(self.used)
        self.n_body = int(self.matrix.shape[1] - 3 * n_tri)
        self.used_faces = np.ascontiguousarray(self.faces[self.used], dtype=np.int64)
        # the same matrix with the normal- and tangent-vertex columns of the
        # used triangles packed right after the body columns: evaluate fills
        # one contiguous (N + 3U, 3) buffer instead of scattering into N + 3T rows
        remap = np.full(n_tri, -1, dtype=np.int64)
        remap[self.used] = np.arange(n_used)
        m = self.matrix.tocoo()
        extra = np.maximum(m.col - self.n_body, 0)
        cols = np.where(m.col < self.n_body, m.col,
                        self.n_body + (extra // n_tri) * n_used + remap[extra % n_tri])
        self.compact = sp.csr_matrix((m.data, (m.row, cols)),
                                      shape=(self.matrix.shape[0], self.n_body + 3 * n_used))
        self.compact.sort_indices()
        self._buf = np.zeros((self.compact.shape[1], 3))

    @property
    def n_items(self) -> int:
        return int(self.matrix.shape[0])

    def normal_vertices(self, body_points: np.ndarray, triangles: np.ndarray | None = None) -> np.ndarray:
        """v1 + unit normal for ``triangles`` (default: all), shape (..., T, 3)."""
        f = self.faces if triangles is None else self.faces[triangles]
        p = np.asarray(body_points, dtype=np.float64)
        v1 = p[..., f[:, 0], :]
        e1 = p[..., f[:, 1], :] - v1
        e2 = p[..., f[:, 2], :] - v1
        n = np.cross(e1, e2)
        ln = np.sqrt(np.einsum("...i,...i->...", n, n))
        return v1 + n / np.where(ln < 1e-300, 1.0, ln)[..., None]

    def frame_vertices(self, body_points: np.ndarray, triangles: np.ndarray | None = None) -> np.ndarray:
        """[v1 + n; v1 + t1; v1 + t2] for ``triangles`` (default: all), shape
        (..., 3T, 3): n the unit normal, t1 the unit bisector of the edges at
        v1, t2 = n x t1."""
        f = self.faces if triangles is None else self.faces[triangles]
        p = np.asarray(body_points, dtype=np.float64)
        v1 = p[..., f[:, 0], :]
        n, t1, t2 = tangent_frames_numpy(p, f)
        return np.concatenate([v1 + n, v1 + t1, v1 + t2], axis=-2)

    def stacked(self, body_points: np.ndarray) -> np.ndarray:
        """[body points (N, 3); normal vertices v1 + n (T, 3); tangent
        vertices v1 + t1 (T, 3), v1 + t2 (T, 3)] -> (N + 3T, 3)."""
        p = np.asarray(body_points, dtype=np.float64)
        return np.concatenate([p, self.frame_vertices(p)], axis=0)

    def evaluate(self, body_points: np.ndarray) -> np.ndarray:
        """Item points for new body points (N, 3) -> (M, 3); or a batch
        (F, N, 3) -> (F, M, 3). One sparse product per call."""
        p = np.asarray(body_points, dtype=np.float64)
        if p.ndim == 2:
            # compiled, or its numpy twin without numba
            return binding_eval(np.ascontiguousarray(p), self.used_faces, self.compact, self._buf)
        f = p.shape[0]
        st = np.empty((self.compact.shape[1], f, 3))
        st[:self.n_body] = p.transpose(1, 0, 2)
        st[self.n_body:] = self.frame_vertices(p, self.used).transpose(1, 0, 2)
        # (N + U, F*3): one product for the whole batch
        out = self.compact @ st.reshape(len(st), f * 3)
        return out.reshape(-1, f, 3).transpose(1, 0, 2)

    def body_patch(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The body vertices the item vertices ``rows`` (P,) are bound to,
        (Q,) sorted, and their summed binding weights (Q,) (each bound
        triangle's weight given to each of its corners; vertices of weight 0
        left out)."""
        corner = self.faces[self.triangles[rows]]  # (P, k, 3)
        w = np.bincount(corner.ravel(), weights=np.repeat(np.asarray(self.weights[rows]).ravel(), 3))
        verts = np.flatnonzero(w > 0)
        return verts, w[verts]

    def clearance_offsets(self) -> np.ndarray:
        """(M,) weighted offset along the bound triangles' normals (an
        estimate of each vertex's clearance on the reference body)."""
        return np.einsum("mk,mk->m", self.weights, self.local[..., 2])


def _group_masks(candidate_mask, n_items: int, n_tris: int):
    """Normalise ``candidate_mask`` to a list of (item vertex indices,
    allowed triangle indices)."""
    if candidate_mask is None:
        return [(np.arange(n_items), np.arange(n_tris))]
    if isinstance(candidate_mask, tuple) and len(candidate_mask) == 2:
        tri_labels, allowed = candidate_mask
        tri_labels = np.asarray(tri_labels)
        allowed = np.asarray(allowed)
        if allowed.ndim == 1:  # one region label per item vertex
            labels = np.unique(allowed)
            return [(np.flatnonzero(allowed == r), np.flatnonzero(tri_labels == r)) for r in labels]
        # (M, R) boolean: allowed regions per item vertex
        allowed = allowed.astype(bool)
        if allowed.shape[1] <= 62:  # rows as bit masks: a 1-D unique, much faster than axis=0
            _, first, inv = np.unique(allowed @ (np.int64(1) << np.arange(allowed.shape[1], dtype=np.int64)),
                                      return_index=True, return_inverse=True)
            combos = allowed[first]
        else:
            combos, inv = np.unique(allowed, axis=0, return_inverse=True)
        inv = inv.ravel()
        out = []
        for ci, row in enumerate(combos):
            out.append((np.flatnonzero(inv == ci), np.flatnonzero(row[tri_labels])))
        return out
    m = np.asarray(candidate_mask)
    if m.dtype == bool and m.shape == (n_tris,):
        return [(np.arange(n_items), np.flatnonzero(m))]
    raise ValueError("candidate_mask: expected None, a (T,) bool mask, or "
                     "(triangle_labels (T,), allowed (M,) labels or (M, R) bool)")


CANDIDATES_PER_K = 3  # nearest centroids examined per bound triangle (plus the nearest vertex's ring)


def _nearest_triangles(body: np.ndarray, faces: np.ndarray, centroids: np.ndarray, allowed: np.ndarray,
                       q: np.ndarray, kk: int):
    """The ``kk`` triangles of ``allowed`` nearest to each point of q (V, 3)
    by point-to-triangle distance, nearest first: indices (V, kk) and
    distances (V, kk).

    Candidates are the nearest centroids (``CANDIDATES_PER_K`` x kk + 4 of
    them) and every allowed triangle around the nearest vertex of the
    allowed triangles, which holds the closest point also when a large
    triangle's centroid is far from a point lying right over it.
    """
    n_c = min(len(allowed), CANDIDATES_PER_K * kk + 4)
    _, ci = cKDTree(centroids[allowed]).query(q, k=n_c)
    ci = allowed[np.asarray(ci).reshape(len(q), n_c)]
    sub = faces[allowed]
    verts, local = np.unique(sub.ravel(), return_inverse=True)
    local = local.reshape(-1, 3)
    _, vi = cKDTree(body[verts]).query(q, k=1)
    # allowed triangles around each vertex, padded with the first
    inc = sp.csr_matrix((np.ones(local.size), (local.ravel(), np.repeat(np.arange(len(sub)), 3))),
                        shape=(len(verts), len(sub)))
    deg = np.diff(inc.indptr)
    w = int(deg.max())
    pos = np.minimum(np.arange(w)[None, :], deg[vi][:, None] - 1)
    ring = allowed[inc.indices[inc.indptr[vi][:, None] + pos]]
    cand = np.concatenate([ci, ring], axis=1)
    f = faces[cand]
    cp, _, _ = closest_point_on_triangles(q[:, None, :], body[f[..., 0]], body[f[..., 1]], body[f[..., 2]])
    d = np.linalg.norm(q[:, None, :] - cp, axis=-1)
    # each triangle once: duplicates (same index) after the first go to inf
    order = np.argsort(cand, axis=1, kind="stable")
    cs = np.take_along_axis(cand, order, axis=1)
    dup = np.zeros_like(cs, dtype=bool)
    dup[:, 1:] = cs[:, 1:] == cs[:, :-1]
    ds = np.where(dup, np.inf, np.take_along_axis(d, order, axis=1))
    best = np.argsort(ds, axis=1, kind="stable")[:, :kk]
    return np.take_along_axis(cs, best, axis=1), np.take_along_axis(ds, best, axis=1)


def bind(body_points: np.ndarray, body_faces: np.ndarray, item_points: np.ndarray,
         k: int = 5, candidate_mask=None, eps: float = 1e-9) -> Binding:
    """Bind item vertices (M, 3) to the body (points (N, 3), faces (T, 3)).

    k: triangles per item vertex (nearest by point-to-triangle distance); an
        int, or (M,) ints (rows with fewer are padded with weight-0 repeats
        of their last triangle up to the largest).
    candidate_mask: restricts the triangles each vertex may use:
        None (all), a (T,) bool mask, or ``(tri_labels (T,), allowed)`` with
        ``allowed`` either (M,) one region label per vertex or (M, R) bool
        (vertex i may use triangle t iff ``allowed[i, tri_labels[t]]``).
    Degenerate (zero-area) triangles are never used.
    """
    body = np.asarray(body_points, dtype=np.float64)
    faces = np.asarray(body_faces, dtype=np.int64)
    q = np.asarray(item_points, dtype=np.float64)
    n_tri, m = len(faces), len(q)
    if m == 0:
        raise ValueError("bind: no item points")
    k_rows = np.broadcast_to(np.asarray(k, dtype=np.int64), (m,))
    if k_rows.min() < 1:
        raise ValueError("bind: k must be >= 1")
    k = int(k_rows.max())
    e1, e2, nrm, area2 = triangle_frames(body, faces)
    scale = np.median(area2[area2 > 0]) if np.any(area2 > 0) else 1.0
    good = area2 > 1e-10 * scale
    centroids = body[faces].mean(axis=1)

    tri_idx = np.zeros((m, k), dtype=np.int64)
    cdist = np.zeros((m, k))
    radius = np.zeros(m)
    for group, allowed in _group_masks(candidate_mask, m, n_tri):
        if len(group) == 0:
            continue
        allowed = allowed[good[allowed]]
        if len(allowed) == 0:
            raise ValueError("bind: some item vertices have no usable candidate triangle")
        for kv in np.unique(k_rows[group]):
            verts = group[k_rows[group] == kv]
            kk = min(int(kv) + 1, len(allowed))
            i, d = _nearest_triangles(body, faces, centroids, allowed, q[verts], kk)
            use = min(int(kv), kk)
            ti = np.empty((len(verts), k), dtype=np.int64)
            dd = np.empty((len(verts), k))
            ti[:, :use] = i[:, :use]
            dd[:, :use] = d[:, :use]
            if use < k:  # fewer candidates than k: repeat the last one (weight 0 below)
                ti[:, use:] = i[:, use - 1:use]
                dd[:, use:] = np.inf
            tri_idx[verts] = ti
            cdist[verts] = dd
            radius[verts] = d[:, -1] if kk > kv else np.inf

    # smooth inverse-distance weights, 0 at the (k+1)-th candidate (Shepard/Franke)
    r = radius[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(np.isfinite(r), np.clip(r - cdist, 0.0, None) / (r * cdist + eps),
                     1.0 / (cdist + eps)) ** 2
    w = np.where(np.isfinite(cdist), w, 0.0)
    s = w.sum(axis=1, keepdims=True)
    flat = s[:, 0] <= 0  # ties at the cut-off distance: plain inverse distance
    if np.any(flat):
        w[flat] = np.where(np.isfinite(cdist[flat]), 1.0 / (cdist[flat] + eps) ** 2, 0.0)
        s = w.sum(axis=1, keepdims=True)
    w = w / s

    return _assemble(body, faces, q, tri_idx, w, e1, e2, nrm)


def _assemble(body: np.ndarray, faces: np.ndarray, q: np.ndarray, tri_idx: np.ndarray, w: np.ndarray,
              e1: np.ndarray, e2: np.ndarray, nrm: np.ndarray) -> Binding:
    """The :class:`Binding` of item points q (M, 3) to the triangles tri_idx
    (M, k) with blend weights w (M, k): local coordinates in each triangle
    (edges e1, e2 and unit normals nrm (T, 3) of the body) and the sparse
    matrix.

    Only the entries of nonzero weight are computed (their ``local`` is 0
    elsewhere; every use weighs it): a binding blended across seams and
    skirt proxies (:func:`blend_rows`) is up to 65 wide with 13 % of its
    entries in use.
    """
    n_body, n_tri, m, k = len(body), len(faces), len(q), tri_idx.shape[1]
    r, j = np.nonzero(w)  # row-major: each row's entries in their order
    t = tri_idx[r, j]
    we = w[r, j]
    f = faces[t]  # (E, 3)
    v1 = body[f[:, 0]]
    d = q[r] - v1
    a1, a2, nn = e1[t], e2[t], nrm[t]
    c = np.einsum("ei,ei->e", d, nn)
    dp = d - c[:, None] * nn  # in-plane part: solve a*e1 + b*e2 = dp
    g11 = np.einsum("ei,ei->e", a1, a1)
    g12 = np.einsum("ei,ei->e", a1, a2)
    g22 = np.einsum("ei,ei->e", a2, a2)
    r1 = np.einsum("ei,ei->e", a1, dp)
    r2 = np.einsum("ei,ei->e", a2, dp)
    det = g11 * g22 - g12 * g12
    det = np.where(np.abs(det) < 1e-300, 1e-300, det)
    local = np.zeros((m, k, 3))
    local[r, j] = np.stack([(g22 * r1 - g12 * r2) / det, (g11 * r2 - g12 * r1) / det, c], axis=-1)

    # the in-plane part from the closest point of the triangle (barycentric,
    # follows the triangle's stretch) plus the rest in the triangle's
    # orthonormal frame (turns with it, does not stretch): a vertex beyond a
    # triangle's edge (a skirt's hem below the hips, a neighbour triangle's
    # vertex) is not thrown by that triangle's local stretch times its
    # distance in triangle sizes; inside the triangle this is the plain
    # barycentric binding
    _, bary, _ = closest_point_on_triangles(q[r] - c[:, None] * nn, v1, v1 + a1, v1 + a2)
    ac, bc = bary[:, 1], bary[:, 2]
    res = dp - ac[:, None] * a1 - bc[:, None] * a2
    _, t1, t2 = frame_from_edges(a1, a2)
    r1 = np.einsum("ei,ei->e", res, t1)
    r2 = np.einsum("ei,ei->e", res, t2)

    # sparse matrix: columns v1, v2, v3 (body), N + t (normal vertex),
    # N + T + t and N + 2T + t (tangent vertices)
    cols = np.stack([f[:, 0], f[:, 1], f[:, 2], n_body + t, n_body + n_tri + t, n_body + 2 * n_tri + t])
    vals = np.stack([we * (1.0 - ac - bc - c - r1 - r2), we * ac, we * bc, we * c, we * r1, we * r2])
    mat = sp.csr_matrix((vals.ravel(), (np.tile(r, 6), cols.ravel())), shape=(m, n_body + 3 * n_tri))
    mat.sum_duplicates()
    mat.eliminate_zeros()
    mat.sort_indices()
    used = np.unique(t[we > 0])
    rcols = np.stack([f[:, 0], n_body + n_tri + t, n_body + 2 * n_tri + t])
    rvals = np.stack([-we * (r1 + r2), we * r1, we * r2])
    rest = sp.csr_matrix((rvals.ravel(), (np.tile(r, 3), rcols.ravel())), shape=(m, n_body + 3 * n_tri))
    rest.sum_duplicates()
    rest.eliminate_zeros()
    return Binding(matrix=mat, faces=faces, triangles=tri_idx, weights=w, local=local, used=used, rest=rest)


def blend_rows(binding: Binding, body_points: np.ndarray, item_points: np.ndarray, rows: np.ndarray,
               second: Binding, share: np.ndarray) -> Binding:
    """``binding`` with the vertices ``rows`` bound partly by ``second``.

    Row ``rows[i]`` becomes ``(1 - share[i]) x`` its own triangles and
    weights plus ``share[i] x`` those of row ``i`` of ``second`` (a binding
    of ``item_points[rows]`` to other triangles of the same body): a vertex
    on the line between two body regions follows both (:mod:`dress.seams`).
    Both bindings reproduce the vertex on ``body_points``, so the blend does.

    Parameters
    ----------
    binding : Binding of M item vertices; body_points (N, 3) and
        item_points (M, 3) it was built on.
    rows : (R,) int; second : Binding of the R vertices ``item_points[rows]``;
        share : (R,) float in [0, 1].

    Returns
    -------
    Binding with k = ``binding.k + second.k`` triangles per row (rows not
    blended: weight-0 repeats of their last triangle).
    """
    rows = np.asarray(rows, dtype=np.int64)
    share = np.asarray(share, dtype=np.float64)
    if len(rows) == 0:
        return binding
    if len(rows) != second.n_items or len(share) != len(rows):
        raise ValueError(f"blend_rows: {len(rows)} rows, {second.n_items} second rows, {len(share)} shares")
    k1, k2 = binding.triangles.shape[1], second.triangles.shape[1]
    tri = np.concatenate([binding.triangles, np.repeat(binding.triangles[:, -1:], k2, axis=1)], axis=1)
    w = np.concatenate([binding.weights, np.zeros((binding.n_items, k2))], axis=1)
    tri[rows, k1:] = second.triangles
    w[rows, :k1] *= (1.0 - share)[:, None]
    w[rows, k1:] = share[:, None] * second.weights
    body = np.asarray(body_points, dtype=np.float64)
    e1, e2, nrm, _ = triangle_frames(body, binding.faces)
    return _assemble(body, binding.faces, np.asarray(item_points, dtype=np.float64), tri, w, e1, e2, nrm)


def rebind(binding: Binding, body_points: np.ndarray, item_points: np.ndarray) -> Binding:
    """``binding``'s triangles and blend weights, with item points (M, 3)
    stored where they are now on body points (N, 3) of the same topology.

    Choosing the triangles is most of :func:`bind`'s cost; an animation binds
    the dressed items to the posed target with the triangles the reference
    chose in its rest pose (limbs apart), which also keeps a vertex from
    switching to a limb that the pose brings close."""
    body = np.asarray(body_points, dtype=np.float64)
    q = np.asarray(item_points, dtype=np.float64)
    if body.shape[0] != binding.n_body or q.shape[0] != binding.n_items:
        raise ValueError(f"rebind: {len(body)} body / {len(q)} item points for a binding of "
                         f"{binding.n_body} / {binding.n_items}")
    e1, e2, nrm, _ = triangle_frames(body, binding.faces)
    return _assemble(body, binding.faces, q, binding.triangles, binding.weights, e1, e2, nrm)


def local_signed_distance(binding: Binding, body_points: np.ndarray, item_points: np.ndarray):
    """Signed distance (M,) from each item vertex to the union of its own bound
    triangles on ``body_points`` (sign from the closest triangle's normal),
    and that closest point (M, 3). A cheap local estimate of the clearance."""
    p = np.asarray(body_points, dtype=np.float64)
    f = binding.faces[binding.triangles]  # (M, k, 3)
    q = np.asarray(item_points, dtype=np.float64)[:, None, :]
    cp, _, _ = closest_point_on_triangles(q, p[f[..., 0]], p[f[..., 1]], p[f[..., 2]])
    diff = q - cp
    d2 = np.einsum("mki,mki->mk", diff, diff)
    best = np.argmin(d2, axis=1)
    r = np.arange(len(f))
    fb = f[r, best]
    n = np.cross(p[fb[:, 1]] - p[fb[:, 0]], p[fb[:, 2]] - p[fb[:, 0]])
    sign = np.where(np.einsum("mi,mi->m", diff[r, best], n) < 0, -1.0, 1.0)
    return sign * np.sqrt(d2[r, best]), cp[r, best]
