"""Bind item vertices to a body surface ("fit metric"), evaluate as one sparse product.

Each item vertex ``p`` is bound to its ``k`` nearest body triangles (by
centroid). In triangle ``t = (v1, v2, v3)`` with unit normal ``n`` it is stored
as local coordinates ``(a, b, c)``:

    p = v1 + a (v2 - v1) + b (v3 - v1) + c n          (c = offset along n)

With Sumner's fourth vertex ``v4 = v1 + n`` this is linear in the stacked
vector ``[v1, v2, v3, v4]``: ``p = (1-a-b-c) v1 + a v2 + b v3 + c v4``. The
``k`` triangles are blended with smooth inverse-distance weights that reach 0
at the (k+1)-th candidate's distance (so the binding is continuous over the
item). Everything is one sparse matrix ``W`` (M, N + T) acting on
``stacked = [body points (N, 3); normal vertices (T, 3)]``.

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

    matrix: (M, N + T) CSR, item = matrix @ stacked(body_points).
    faces: (T, 3) body triangles.
    triangles: (M, k) bound triangle of each item vertex, nearest first.
    weights: (M, k) blend weights (rows sum to 1).
    local: (M, k, 3) local (a, b, c) coordinates; c = offset along the unit
        normal (the vertex's clearance above that triangle's plane).
    used: (U,) sorted indices of the triangles any vertex is bound to; only
        their normal vertices are computed by :meth:`evaluate`.
    """
    matrix: sp.csr_matrix
    faces: np.ndarray
    triangles: np.ndarray
    weights: np.ndarray
    local: np.ndarray
    used: np.ndarray

    def __post_init__(self):
        self.n_body = int(self.matrix.shape[1] - len(self.faces))
        self.used_faces = np.ascontiguousarray(self.faces[self.used], dtype=np.int64)
        # the same matrix with the normal-vertex columns of the used
        # triangles packed right after the body columns: evaluate fills one
        # contiguous (N + U, 3) buffer instead of scattering into N + T rows
        remap = np.full(len(self.faces), -1, dtype=np.int64)
        remap[self.used] = np.arange(len(self.used))
        m = self.matrix.tocoo()
        cols = np.where(m.col < self.n_body, m.col, self.n_body + remap[np.maximum(m.col - self.n_body, 0)])
        self.compact = sp.csr_matrix((m.data, (m.row, cols)),
                                      shape=(self.matrix.shape[0], self.n_body + len(self.used)))
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

    def stacked(self, body_points: np.ndarray) -> np.ndarray:
        """[body points (N, 3); normal vertices v1 + n (T, 3)] -> (N + T, 3)."""
        p = np.asarray(body_points, dtype=np.float64)
        return np.concatenate([p, self.normal_vertices(p)], axis=0)

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
        st[self.n_body:] = self.normal_vertices(p, self.used).transpose(1, 0, 2)
        # (N + U, F*3): one product for the whole batch
        out = self.compact @ st.reshape(len(st), f * 3)
        return out.reshape(-1, f, 3).transpose(1, 0, 2)

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


def bind(body_points: np.ndarray, body_faces: np.ndarray, item_points: np.ndarray,
         k: int = 5, candidate_mask=None, eps: float = 1e-9) -> Binding:
    """Bind item vertices (M, 3) to the body (points (N, 3), faces (T, 3)).

    k: triangles per item vertex (nearest centroids).
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
    k = int(k)
    if k < 1:
        raise ValueError("bind: k must be >= 1")
    e1, e2, nrm, area2 = triangle_frames(body, faces)
    scale = np.median(area2[area2 > 0]) if np.any(area2 > 0) else 1.0
    good = area2 > 1e-10 * scale
    centroids = body[faces].mean(axis=1)

    tri_idx = np.zeros((m, k), dtype=np.int64)
    cdist = np.zeros((m, k))
    radius = np.zeros(m)
    for verts, allowed in _group_masks(candidate_mask, m, n_tri):
        if len(verts) == 0:
            continue
        allowed = allowed[good[allowed]]
        if len(allowed) == 0:
            raise ValueError("bind: some item vertices have no usable candidate triangle")
        kk = min(k + 1, len(allowed))
        d, i = cKDTree(centroids[allowed]).query(q[verts], k=kk)
        d = d.reshape(len(verts), kk)
        i = allowed[i.reshape(len(verts), kk)]
        use = min(k, kk)
        ti = np.empty((len(verts), k), dtype=np.int64)
        dd = np.empty((len(verts), k))
        ti[:, :use] = i[:, :use]
        dd[:, :use] = d[:, :use]
        if use < k:  # fewer candidates than k: repeat the last one (weight 0 below)
            ti[:, use:] = i[:, use - 1:use]
            dd[:, use:] = np.inf
        tri_idx[verts] = ti
        cdist[verts] = dd
        radius[verts] = d[:, -1] if kk > k else np.inf

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
    matrix."""
    n_body, n_tri, m, k = len(body), len(faces), len(q), tri_idx.shape[1]
    f = faces[tri_idx]  # (M, k, 3)
    v1 = body[f[..., 0]]
    d = q[:, None, :] - v1
    a1, a2, nn = e1[tri_idx], e2[tri_idx], nrm[tri_idx]
    c = np.einsum("mki,mki->mk", d, nn)
    dp = d - c[..., None] * nn  # in-plane part: solve a*e1 + b*e2 = dp
    g11 = np.einsum("mki,mki->mk", a1, a1)
    g12 = np.einsum("mki,mki->mk", a1, a2)
    g22 = np.einsum("mki,mki->mk", a2, a2)
    r1 = np.einsum("mki,mki->mk", a1, dp)
    r2 = np.einsum("mki,mki->mk", a2, dp)
    det = g11 * g22 - g12 * g12
    det = np.where(np.abs(det) < 1e-300, 1e-300, det)
    a = (g22 * r1 - g12 * r2) / det
    b = (g11 * r2 - g12 * r1) / det
    local = np.stack([a, b, c], axis=-1)

    # sparse matrix: columns v1, v2, v3 (body) and N + t (normal vertex)
    cols = np.concatenate([f[..., 0], f[..., 1], f[..., 2], n_body + tri_idx], axis=1)  # (M, 4k)
    vals = np.concatenate([w * (1.0 - a - b - c), w * a, w * b, w * c], axis=1)
    rows = np.repeat(np.arange(m), 4 * k)
    mat = sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(m, n_body + n_tri))
    mat.sum_duplicates()
    mat.eliminate_zeros()
    mat.sort_indices()
    used = np.unique(tri_idx[w > 0])
    return Binding(matrix=mat, faces=faces, triangles=tri_idx, weights=w, local=local, used=used)


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
