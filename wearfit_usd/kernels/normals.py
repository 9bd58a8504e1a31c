"""Triangle and vertex normals: compiled kernels and their numpy twins.

Face normals (unit or twice the area long), area-weighted vertex normals,
per-vertex sums of unit face normals (the penetration guard's cheap
estimate) and angle-weighted vertex pseudo-normals (the sign of a closest
point at a mesh corner). ``face_normals`` and ``vertex_normals`` run the
compiled kernel when numba is in use, their numpy twin otherwise; the tests
check that both give the same numbers.

points (N, 3) float64, faces (T, 3) int64; lengths in the units of the points.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .jit import HAVE_NUMBA, jit


@jit(inline=True)
def corner_edges(points, a, b, c):
    """The two edges b - a and c - a leaving corner a, as six scalars."""
    return (points[b, 0] - points[a, 0], points[b, 1] - points[a, 1], points[b, 2] - points[a, 2],
            points[c, 0] - points[a, 0], points[c, 1] - points[a, 1], points[c, 2] - points[a, 2])


@jit(inline=True)
def face_cross(points, faces, f):
    """(b - a) x (c - a) of triangle f = (a, b, c): its normal, twice the
    area long."""
    ax, ay, az, bx, by, bz = corner_edges(points, faces[f, 0], faces[f, 1], faces[f, 2])
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@jit
def face_normals_into(points, faces, unit, out):
    """out (T, 3) = normals of faces (T, 3) on points (N, 3): unit (zero-area
    faces: the zero vector) or, if not ``unit``, twice the area long."""
    for f in range(faces.shape[0]):
        nx, ny, nz = face_cross(points, faces, f)
        ln = np.sqrt(nx * nx + ny * ny + nz * nz) if unit else 1.0
        if ln < 1e-300:
            ln = 1.0
        out[f, 0] = nx / ln
        out[f, 1] = ny / ln
        out[f, 2] = nz / ln


@jit
def _vertex_normals(points, faces, out):
    """out (N, 3) = area-weighted unit vertex normals: the sum of the
    adjacent faces' cross products (faces in index order), normalised
    (zero sums stay zero)."""
    out[:] = 0.0
    for f in range(faces.shape[0]):
        nx, ny, nz = face_cross(points, faces, f)
        for c in range(3):
            v = faces[f, c]
            out[v, 0] += nx
            out[v, 1] += ny
            out[v, 2] += nz
    for v in range(out.shape[0]):
        ln = np.sqrt(out[v, 0] * out[v, 0] + out[v, 1] * out[v, 1] + out[v, 2] * out[v, 2])
        if ln < 1e-300:
            ln = 1.0
        out[v, 0] /= ln
        out[v, 1] /= ln
        out[v, 2] /= ln


@jit
def face_normal_sums(faces, face_n, vsum):
    """Per-vertex sums vsum (N, 3) of the adjacent faces' unit normals face_n
    (T, 3), faces added in index order (as the sparse incidence product of
    :func:`face_normal_sums_numpy` does)."""
    vsum[:] = 0.0
    for f in range(faces.shape[0]):
        for k in range(3):
            v = faces[f, k]
            vsum[v, 0] += face_n[f, 0]
            vsum[v, 1] += face_n[f, 1]
            vsum[v, 2] += face_n[f, 2]


@jit
def vertex_pseudo_normal(v, points, faces, ring, face_n):
    """Angle-weighted pseudo-normal (not unit) of vertex v from its ring of
    triangles ring[v] (padded by repeating the first one)."""
    nx = 0.0
    ny = 0.0
    nz = 0.0
    first = ring[v, 0]
    for k in range(ring.shape[1]):
        f = ring[v, k]
        if k > 0 and f == first:
            continue
        for c in range(3):
            if faces[f, c] != v:
                continue
            e1x, e1y, e1z, e2x, e2y, e2z = corner_edges(points, faces[f, c], faces[f, (c + 1) % 3],
                                                        faces[f, (c + 2) % 3])
            ln = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z) * np.sqrt(e2x * e2x + e2y * e2y + e2z * e2z)
            cosang = (e1x * e2x + e1y * e2y + e1z * e2z) / max(ln, 1e-300)
            ang = np.arccos(min(max(cosang, -1.0), 1.0))
            nx += face_n[f, 0] * ang
            ny += face_n[f, 1] * ang
            nz += face_n[f, 2] * ang
    return nx, ny, nz


# ----------------------------------------------------------------------------
# numpy twins

def face_normals_numpy(points: np.ndarray, faces: np.ndarray, unit: bool = True) -> np.ndarray:
    """:func:`face_normals` in numpy: (T, 3) normals of faces (T, 3) on
    points (N, 3), unit (zero-area faces: zero) or twice the area long."""
    p0 = points[faces[:, 0]]
    a = points[faces[:, 1]] - p0
    b = points[faces[:, 2]] - p0
    n = np.empty_like(a)
    n[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    n[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    n[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    if unit:
        ln = np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]
        n /= np.where(ln < 1e-300, 1.0, ln)
    return n


def vertex_incidence(faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(n_vertices, T) CSR vertex-face incidence of faces (T, 3): ``incidence
    @ per-face values`` sums them over each vertex's faces in index order."""
    t = len(faces)
    return sp.csr_matrix((np.ones(3 * t), (np.asarray(faces).ravel(), np.repeat(np.arange(t), 3))),
                         shape=(n_vertices, t))


def vertex_normals_numpy(points: np.ndarray, faces: np.ndarray,
                         incidence: sp.csr_matrix | None = None) -> np.ndarray:
    """:func:`vertex_normals` in numpy: (N, 3) area-weighted unit vertex
    normals through the sparse ``incidence`` (:func:`vertex_incidence`,
    built here if not given)."""
    if incidence is None:
        incidence = vertex_incidence(faces, len(points))
    vn = incidence @ face_normals_numpy(points, faces, unit=False)
    ln = np.linalg.norm(vn, axis=1, keepdims=True)
    return vn / np.where(ln < 1e-300, 1.0, ln)


def face_normal_sums_numpy(faces: np.ndarray, face_n: np.ndarray, vsum: np.ndarray) -> None:
    """:func:`face_normal_sums` in numpy: vsum (N, 3) = sums of the adjacent
    faces' unit normals face_n (T, 3)."""
    vsum[:] = vertex_incidence(faces, len(vsum)) @ face_n


def corner_normals_numpy(tris: np.ndarray, points: np.ndarray, faces: np.ndarray,
                         face_n: np.ndarray) -> np.ndarray:
    """(len(tris) * 3, 3) unit face normal face_n (T, 3) times corner angle
    for the corners of triangles ``tris``, corners in order."""
    tri = points[faces[tris]]
    e1 = np.roll(tri, -1, axis=1) - tri      # corner c: edge to c+1
    e2 = np.roll(tri, -2, axis=1) - tri      # corner c: edge to c+2
    cosang = np.einsum("tcj,tcj->tc", e1, e2) / np.maximum(
        np.linalg.norm(e1, axis=2) * np.linalg.norm(e2, axis=2), 1e-300)
    ang = np.arccos(np.clip(cosang, -1.0, 1.0))  # (t, 3)
    return (face_n[tris][:, None, :] * ang[:, :, None]).reshape(-1, 3)


def vertex_pseudo_normals_numpy(verts: np.ndarray, points: np.ndarray, faces: np.ndarray, ring: np.ndarray,
                                face_n: np.ndarray) -> np.ndarray:
    """:func:`vertex_pseudo_normal` for vertices verts (V,) at once: (V, 3)
    angle-weighted pseudo-normals (not unit) through their rings of
    triangles ring (N, w) (padded by repeating the first one)."""
    uniq, inv = np.unique(verts, return_inverse=True)
    rg = ring[uniq]                         # (U, w) triangles, padded by repeats
    first = np.concatenate([np.ones((len(uniq), 1), bool), rg[:, 1:] != rg[:, :1]], axis=1)
    cn = corner_normals_numpy(rg.ravel(), points, faces, face_n).reshape(len(uniq), rg.shape[1], 3, 3)
    corner = faces[rg] == uniq[:, None, None]  # (U, w, 3): which corner is the vertex
    vn = np.einsum("uwc,uwcj->uj", corner * first[:, :, None], cn)
    return vn[inv]


# ----------------------------------------------------------------------------
# the public kernels: compiled with numba, the numpy twin otherwise

def face_normals(points: np.ndarray, faces: np.ndarray, unit: bool = True) -> np.ndarray:
    """(T, 3) normals of faces (T, 3) on points (N, 3): unit (zero-area
    faces: the zero vector) or, if not ``unit``, twice the area long."""
    if not HAVE_NUMBA:
        return face_normals_numpy(points, faces, unit)
    out = np.empty((len(faces), 3))
    face_normals_into(np.ascontiguousarray(points, dtype=np.float64),
                      np.ascontiguousarray(faces, dtype=np.int64), bool(unit), out)
    return out


def vertex_normals(points: np.ndarray, faces: np.ndarray, incidence: sp.csr_matrix | None = None) -> np.ndarray:
    """(N, 3) area-weighted unit vertex normals of the mesh (points (N, 3),
    faces (T, 3)); zero where no face has area. ``incidence``: the numpy
    path's (N, T) operator (:func:`vertex_incidence`), when the caller keeps
    one per topology."""
    if not HAVE_NUMBA:
        return vertex_normals_numpy(points, faces, incidence)
    out = np.empty((len(points), 3))
    _vertex_normals(np.ascontiguousarray(points, dtype=np.float64),
                    np.ascontiguousarray(faces, dtype=np.int64), out)
    return out
