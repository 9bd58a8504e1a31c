"""The body under the items: faces the items cover, to hide or delete.

A body vertex is *covered* by an item when a ray from it along the body
normal meets the item between ``inset`` under the skin and ``reach`` above
it: the coverage ray test of the motion measures
(:func:`geometry.rays.cast_rays`, 8 cm out; 25 mm in instead of 5 mm, see
:data:`INSET`). A body polygon is
*hidden* when all its corners and its centre are covered (by one item for
that item's set, by any item for the union): MakeHuman's ``delete_verts``
found from the geometry instead of authored per asset.

For a shot, :func:`hidden_polygons` with ``depth`` keeps only the polygons
whose corners lie at least that far (along body edges) from every uncovered
vertex and whose item lies within ``max_gap`` along the normal: motion
slides cuffs, hems and collars over the skin and lifts loose cloth, so the
edge of the covered region and loosely covered skin show through in some
frames (see README, "hidden body", for the walk's measurement).

:func:`drop_polygons` removes polygons from a :class:`~wearfit_usd.model.Mesh`
(points, triangles, skin weights and primvars re-indexed), for engines that
want the body without its hidden faces.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..geometry.closest import VertexNormals
from ..geometry.mesh import edges
from ..geometry.rays import cast_rays
from ..model import Mesh, Primvar

#: the coverage ray segment (metres along the body normal): 8 cm out as the
#: motion measures'; 25 mm in (theirs: 5 mm), so that skin poking through an
#: item dipped into the body (MakeHuman suits: folds up to 10 mm deep on
#: their own body, deeper on others) counts as covered
REACH = 0.08
INSET = 0.025
#: shots: covered polygons this far (metres, along body edges) inside the covered region ...
SHOT_DEPTH = 0.03
#: ... under an item no farther than this along the normal
SHOT_MAX_GAP = 0.03


@dataclass
class Coverage:
    """Per item, per body vertex: covered (I, N) bool and the distance
    along the normal to the item (I, N), inf where not covered; per item,
    per polygon, whether its centre is covered (I, P) bool, tested only for
    the polygons whose every corner some item covers (False elsewhere:
    those cannot be hidden)."""
    names: list
    vertex: np.ndarray
    gap: np.ndarray
    centre: np.ndarray


def coverage(body_points: np.ndarray, body_faces: np.ndarray, counts: np.ndarray, indices: np.ndarray,
             items: list, reach: float = REACH, inset: float = INSET) -> Coverage:
    """The coverage ray test of every body vertex and polygon centre.

    Parameters
    ----------
    body_points : (N, 3) body points (internal space, metres).
    body_faces : (T, 3) body triangles (normals).
    counts, indices : the body's polygons (faceVertexCounts (P,), faceVertexIndices).
    items : list of (name, points (M_i, 3), faces (F_i, 3)).
    reach, inset : the ray segment along the normal (metres).
    """
    pts = np.asarray(body_points, dtype=np.float64)
    nrm = VertexNormals(np.asarray(body_faces, dtype=np.int64), len(pts))(pts)
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    poly = np.repeat(np.arange(len(counts)), counts)
    cen = np.zeros((len(counts), 3))
    np.add.at(cen, poly, pts[indices])
    cen /= counts[:, None]
    cn = np.zeros((len(counts), 3))
    np.add.at(cn, poly, nrm[indices])
    cn /= np.maximum(np.linalg.norm(cn, axis=1, keepdims=True), 1e-12)
    names, vert, gap = [], [], []
    meshes = [(np.asarray(ip, dtype=np.float64), np.asarray(ifc, dtype=np.int64)) for _, ip, ifc in items]
    for (name, _, _), (ip, ifc) in zip(items, meshes):
        hit = cast_rays(pts, nrm, ip, ifc, -inset, reach)
        g = np.full(len(pts), np.inf)
        v = np.flatnonzero(hit >= 0)
        if len(v):
            tri = ip[ifc[hit[v]]]
            # distance along the normal to the hit triangle's plane
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            den = np.einsum("ij,ij->i", n, nrm[v])
            ok = np.abs(den) > 1e-15
            t = np.einsum("ij,ij->i", n, tri[:, 0] - pts[v]) / np.where(ok, den, 1.0)
            g[v] = np.where(ok, t, 0.0)
        names.append(name)
        vert.append(hit >= 0)
        gap.append(g)
    n, p = len(pts), len(counts)
    vert = np.array(vert).reshape(-1, n)
    # the centres only of polygons whose corners some item covers: no other
    # can be hidden (ref_male on body_male_heavy: 0.48 -> 0.44 s, the same subsets)
    centre = np.zeros((len(items), p), dtype=bool)
    if len(items):
        cand = np.flatnonzero(_all_corners(vert.any(axis=0), counts, indices))
        for i, (ip, ifc) in enumerate(meshes):
            centre[i, cand] = cast_rays(cen[cand], cn[cand], ip, ifc, -inset, reach) >= 0
    return Coverage(names, vert, np.array(gap).reshape(-1, n), centre)


def _all_corners(mask: np.ndarray, counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(P,) whether every corner of each polygon is in (N,) ``mask``."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return np.minimum.reduceat(mask[indices].astype(np.int8), starts).astype(bool)


def _depth(mask: np.ndarray, points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N,) distance along body edges from each vertex to the nearest vertex
    outside ``mask`` (0 outside)."""
    e = edges(faces)
    w = np.linalg.norm(points[e[:, 0]] - points[e[:, 1]], axis=1)
    n = len(points)
    # a virtual source joined to every uncovered vertex
    src = np.flatnonzero(~mask)
    if len(src) == 0:
        return np.full(n, np.inf)
    rows = np.concatenate([e[:, 0], e[:, 1], np.full(len(src), n)])
    cols = np.concatenate([e[:, 1], e[:, 0], src])
    vals = np.concatenate([w, w, np.full(len(src), 1e-12)])
    g = sp.csr_matrix((vals, (rows, cols)), shape=(n + 1, n + 1))
    return dijkstra(g, directed=True, indices=n)[:n]


def hidden_polygons(cov: Coverage, counts: np.ndarray, indices: np.ndarray, body_points: np.ndarray | None = None,
                    body_faces: np.ndarray | None = None, depth: float = 0.0,
                    max_gap: float = np.inf) -> dict:
    """Hidden polygons: ``{"hidden_under_items": (H,) int, "hidden_under_<item>": ...}``
    (polygon indices, sorted; items hiding nothing are left out).

    A polygon is hidden when every corner and its centre are covered (by the
    item, or for the union by any item); with ``depth`` > 0 (shots) a corner
    counts only when it lies at least ``depth`` metres along body edges
    from every vertex the item leaves uncovered (``body_points`` and
    ``body_faces`` needed) and its item is within ``max_gap`` metres.
    """
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    per = [cov.vertex[i] & (cov.gap[i] <= max_gap) for i in range(len(cov.names))]

    def deep(m):
        if depth > 0 and m.any():
            return m & (_depth(m, np.asarray(body_points, dtype=np.float64), np.asarray(body_faces)) >= depth)
        return m
    out = {}
    for i, name in enumerate(cov.names):
        h = _all_corners(deep(per[i]), counts, indices) & cov.centre[i]
        if h.any():
            out[f"hidden_under_{_safe(name)}"] = np.flatnonzero(h)
    if per:
        # the union eroded once: a polygon half under the shirt, half under
        # the trousers is deep in the covered region though at each one's edge
        h = _all_corners(deep(np.any(per, axis=0)), counts, indices) & cov.centre.any(axis=0)
        union = np.flatnonzero(h)
    else:
        union = np.zeros(0, dtype=np.int64)
    return {"hidden_under_items": union, **out}


def _safe(name: str) -> str:
    s = "".join(c if c.isalnum() or c == "_" else "_" for c in name)
    return s or "item"


def drop_polygons(mesh: Mesh, hidden: np.ndarray) -> tuple[Mesh, np.ndarray]:
    """``mesh`` without the polygons ``hidden`` (indices), and the (P,) bool
    mask of the kept ones. Points no kept polygon uses go too; triangles,
    skin weights and primvars (vertex, varying, faceVarying, uniform; indexed
    ones by their indices) are re-indexed."""
    counts = np.asarray(mesh.face_vertex_counts, dtype=np.int64)
    idx = np.asarray(mesh.face_vertex_indices, dtype=np.int64)
    keep = np.ones(len(counts), dtype=bool)
    keep[np.asarray(hidden, dtype=np.int64)] = False
    corner = np.repeat(keep, counts)
    vert = np.zeros(mesh.n_points, dtype=bool)
    vert[idx[corner]] = True
    new_v = np.cumsum(vert) - 1
    new_p = np.cumsum(keep) - 1
    tri_keep = keep[mesh.tri_to_poly]
    sel = {"vertex": vert, "varying": vert, "faceVarying": corner, "uniform": keep}
    pvs = []
    for pv in mesh.primvars:
        s = sel.get(pv.interpolation)
        if s is None:
            pvs.append(pv)
            continue
        if pv.indices is not None:
            if len(pv.indices) == len(s):
                pvs.append(Primvar(pv.name, pv.type_name, pv.interpolation, pv.values, pv.indices[s],
                                   pv.element_size))
            continue
        es = max(int(pv.element_size), 1)
        if len(pv.values) != len(s) * es:
            continue  # malformed: not carried rather than wrong
        pvs.append(Primvar(pv.name, pv.type_name, pv.interpolation, pv.values[np.repeat(s, es)], None,
                           pv.element_size))
    out = Mesh(name=mesh.name, points=mesh.points[vert], faces=new_v[mesh.faces[tri_keep]],
               face_vertex_counts=counts[keep], face_vertex_indices=new_v[idx[corner]],
               tri_to_poly=new_p[mesh.tri_to_poly[tri_keep]], path=mesh.path, primvars=pvs,
               normals_interpolation=mesh.normals_interpolation, left_handed=mesh.left_handed,
               double_sided=mesh.double_sided,
               joint_indices=None if mesh.joint_indices is None else mesh.joint_indices[vert],
               joint_weights=None if mesh.joint_weights is None else mesh.joint_weights[vert],
               display_color=mesh.display_color)
    return out, keep


def hide_or_drop(body: Mesh, body_points: np.ndarray, items: list, delete: bool = False,
                 depth: float = 0.0, max_gap: float = np.inf) -> tuple[Mesh, dict, np.ndarray | None]:
    """The body to write and its hidden subsets.

    Parameters
    ----------
    body : the body as it is written (its polygons and skin).
    body_points : (N, 3) the body the items were dressed on (coverage is
        tested there: the static dress, or a shot's frame 0).
    items : list of (name, points (M_i, 3), faces (F_i, 3)) dressed on it.
    delete : drop the hidden polygons instead of naming them.
    depth, max_gap : see :func:`hidden_polygons` (shots).

    Returns
    -------
    (body to write, {subset name: polygon indices} (empty when deleted),
    (P,) kept-polygon mask or None when nothing was deleted).
    """
    cov = coverage(body_points, body.faces, body.face_vertex_counts, body.face_vertex_indices, items)
    subsets = hidden_polygons(cov, body.face_vertex_counts, body.face_vertex_indices, body_points,
                              body.faces, depth=depth, max_gap=max_gap)
    if not delete:
        return body, subsets, None
    out, keep = drop_polygons(body, subsets["hidden_under_items"])
    return out, {}, keep
