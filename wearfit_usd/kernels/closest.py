"""Closest point on a triangle mesh among candidate triangles: compiled
kernels and their numpy twins.

For each query point and its candidate triangles (M, c): the closest point
(squared distance, parameters s, t of a + s (b - a) + t (c - a), inside the
face or not, which triangle) and, signed, the pseudo-normal of the closest
feature and the signed distance. ``closest_candidates`` and
``closest_signed`` run the compiled kernel when numba is in use, their numpy
twin otherwise; the tests check that both give the same numbers.

points (N, 3) float64, faces (T, 3) int64; lengths in the units of the points.
"""
from __future__ import annotations

import numpy as np

from .jit import HAVE_NUMBA, jit
from .normals import vertex_pseudo_normal, vertex_pseudo_normals_numpy


@jit
def closest_on_triangle(qx, qy, qz, f, points, faces):
    """Closest point of triangle f to (qx, qy, qz): (squared distance, s, t,
    inside) with the point a + s (b - a) + t (c - a); same rules as
    :func:`closest_params` (plane projection inside, else the best
    clamped edge projection; s, t exactly 0 or 1 where clamped)."""
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    ax = points[i0, 0]
    ay = points[i0, 1]
    az = points[i0, 2]
    bx = points[i1, 0] - ax
    by = points[i1, 1] - ay
    bz = points[i1, 2] - az
    cx = points[i2, 0] - ax
    cy = points[i2, 1] - ay
    cz = points[i2, 2] - az
    px = qx - ax
    py = qy - ay
    pz = qz - az
    app = px * px + py * py + pz * pz
    d20 = px * bx + py * by + pz * bz
    d21 = px * cx + py * cy + pz * cz
    e00 = bx * bx + by * by + bz * bz
    e01 = bx * cx + by * cy + bz * cz
    e11 = cx * cx + cy * cy + cz * cz
    den = e00 * e11 - e01 * e01
    inside = False
    s = 0.0
    t = 0.0
    if den > 1e-12 * e00 * e11:
        v = (e11 * d20 - e01 * d21) / den
        w = (e00 * d21 - e01 * d20) / den
        if v >= 0 and w >= 0 and v + w <= 1:
            inside = True
            s = v
            t = w
    if not inside:
        # edge ab (t = 0)
        s = d20 / e00 if e00 > 0 else d20
        s = min(max(s, 0.0), 1.0)
        t = 0.0
        dd = app - 2 * s * d20 + s * s * e00
        # edge ac (s = 0)
        t2 = d21 / e11 if e11 > 0 else d21
        t2 = min(max(t2, 0.0), 1.0)
        d2 = app - 2 * t2 * d21 + t2 * t2 * e11
        if d2 < dd:
            s = 0.0
            t = t2
            dd = d2
        # edge bc (s = 1 - u, t = u)
        ee = e00 - 2 * e01 + e11
        u = (d21 - d20 - e01 + e00) / (ee if ee > 0 else 1.0)
        u = min(max(u, 0.0), 1.0)
        s3 = 1.0 - u
        d3 = app - 2 * s3 * d20 - 2 * u * d21 + s3 * s3 * e00 + 2 * s3 * u * e01 + u * u * e11
        if d3 < dd:
            s = s3
            t = u
    dist = app - 2 * s * d20 - 2 * t * d21 + s * s * e00 + 2 * s * t * e01 + t * t * e11
    if dist < 0.0:
        dist = 0.0
    return dist, s, t, inside


@jit(inline=True)
def _best_candidate(qx, qy, qz, cand, i, points, faces):
    """Closest of the triangles cand[i] (row i of (M, c)) to (qx, qy, qz):
    (squared distance, s, t, inside, triangle) as :func:`closest_on_triangle`
    (first candidate wins ties)."""
    best = np.inf
    bs = 0.0
    bt = 0.0
    bin_ = False
    btri = cand[i, 0]
    for k in range(cand.shape[1]):
        f = cand[i, k]
        dist, s, t, inside = closest_on_triangle(qx, qy, qz, f, points, faces)
        if dist < best:
            best = dist
            bs = s
            bt = t
            bin_ = inside
            btri = f
    return best, bs, bt, bin_, btri


@jit(inline=True)
def point_on(f, s, t, points, faces):
    """The point a + s (b - a) + t (c - a) of triangle f."""
    a = faces[f, 0]
    b = faces[f, 1]
    c = faces[f, 2]
    return (points[a, 0] + s * (points[b, 0] - points[a, 0]) + t * (points[c, 0] - points[a, 0]),
            points[a, 1] + s * (points[b, 1] - points[a, 1]) + t * (points[c, 1] - points[a, 1]),
            points[a, 2] + s * (points[b, 2] - points[a, 2]) + t * (points[c, 2] - points[a, 2]))


@jit(inline=True)
def closest_feature(f, s, t, inside, faces, edge_id):
    """The feature of triangle f that holds its closest point (s, t, inside
    from :func:`closest_on_triangle`), by the rule of geometry.closest's feature codes:
    (edge id, vertex), both -1 for the face itself."""
    e = -1
    v = -1
    if not inside:
        if t == 0:
            if s == 0:
                v = faces[f, 0]
            elif s == 1:
                v = faces[f, 1]
            else:
                e = edge_id[f, 0]
        elif s == 0:
            if t == 1:
                v = faces[f, 2]
            else:
                e = edge_id[f, 2]
        else:
            e = edge_id[f, 1]
    return e, v


@jit
def _closest_candidates(q, cand, points, faces, out_d2, out_s, out_t, out_inside, out_tri):
    """For each query point q[i] (M, 3) the closest point on the candidate
    triangles cand[i] (M, c) of the mesh (points (N, 3), faces (T, 3)).
    Writes the squared distance, the parameters (s, t) of the closest point
    a + s (b - a) + t (c - a), whether it is inside the face, and the
    triangle (first candidate wins ties)."""
    for i in range(cand.shape[0]):
        out_d2[i], out_s[i], out_t[i], out_inside[i], out_tri[i] = _best_candidate(
            q[i, 0], q[i, 1], q[i, 2], cand, i, points, faces)


@jit
def _closest_signed(q, cand, points, faces, face_n, edge_n, edge_id, ring, out_d, out_p, out_tri, out_bary,
                    out_n):
    """:func:`_closest_candidates` finished in the same pass: the closest
    point, barycentrics, the pseudo-normal of the closest feature (face: its
    normal face_n (T, 3); edge k of the face (01, 12, 20): edge_n[edge_id[f,
    k]] (E, 3); corner: the angle-weighted vertex pseudo-normal over ring)
    and the signed distance (negative where the point lies behind that
    normal), as ``SurfaceQuery.closest`` returns them."""
    for i in range(cand.shape[0]):
        best, s, t, inside, f = _best_candidate(q[i, 0], q[i, 1], q[i, 2], cand, i, points, faces)
        out_p[i, 0], out_p[i, 1], out_p[i, 2] = point_on(f, s, t, points, faces)
        out_bary[i, 0] = 1.0 - s - t
        out_bary[i, 1] = s
        out_bary[i, 2] = t
        out_tri[i] = f
        e, v = closest_feature(f, s, t, inside, faces, edge_id)
        if e >= 0:
            nx, ny, nz = edge_n[e, 0], edge_n[e, 1], edge_n[e, 2]
        elif v >= 0:
            nx, ny, nz = vertex_pseudo_normal(v, points, faces, ring, face_n)
        else:
            nx, ny, nz = face_n[f, 0], face_n[f, 1], face_n[f, 2]
        out_n[i, 0] = nx
        out_n[i, 1] = ny
        out_n[i, 2] = nz
        side = (q[i, 0] - out_p[i, 0]) * nx + (q[i, 1] - out_p[i, 1]) * ny + (q[i, 2] - out_p[i, 2]) * nz
        out_d[i] = -np.sqrt(best) if side < 0 else np.sqrt(best)


# ----------------------------------------------------------------------------
# numpy twins

def closest_params(app, d20, d21, d00, d01, d11):
    """Closest point ``a + s ab + t ac`` of triangles to points, from dot
    products only: app = |p-a|^2, d20 = (p-a).ab, d21 = (p-a).ac,
    d00 = ab.ab, d01 = ab.ac, d11 = ac.ac (broadcastable arrays): the numpy
    twin of :func:`closest_on_triangle`.

    Inside the triangle: the plane projection; otherwise the best of the
    three edge projections clamped to the edge (exact; degenerate triangles
    are handled through their edges). Returns (s, t, squared distance,
    inside). On an edge or vertex, s and t are exactly 0 or 1 where clamped.
    """
    def dist2(s, t):
        return np.maximum(app - 2 * s * d20 - 2 * t * d21 + s * s * d00 + 2 * s * t * d01
                          + t * t * d11, 0.0)

    den = d00 * d11 - d01 * d01
    ok = den > 1e-12 * d00 * d11
    sden = np.where(ok, den, 1.0)
    v = (d11 * d20 - d01 * d21) / sden
    w = (d00 * d21 - d01 * d20) / sden
    inside = ok & (v >= 0) & (w >= 0) & (v + w <= 1)
    # edge ab (t = 0), edge ac (s = 0), edge bc (s = 1 - u, t = u)
    s_ab = np.clip(d20 / np.where(d00 > 0, d00, 1.0), 0.0, 1.0)
    t_ac = np.clip(d21 / np.where(d11 > 0, d11, 1.0), 0.0, 1.0)
    ee = d00 - 2 * d01 + d11
    u_bc = np.clip((d21 - d20 - d01 + d00) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
    zero = np.zeros_like(s_ab)
    s_best, t_best = s_ab, zero
    best = dist2(s_ab, zero)
    for s_e, t_e in ((zero, t_ac), (1.0 - u_bc, u_bc)):
        d = dist2(s_e, t_e)
        better = d < best
        s_best = np.where(better, s_e, s_best)
        t_best = np.where(better, t_e, t_best)
        best = np.where(better, d, best)
    s_out = np.where(inside, v, s_best)
    t_out = np.where(inside, w, t_best)
    d_out = np.where(inside, dist2(v, w), best)
    return s_out, t_out, d_out, inside


def closest_candidates_numpy(q, cand, points, faces):
    """:func:`closest_candidates` in numpy (same arguments and results)."""
    q = np.asarray(q, dtype=np.float64)
    a = points[faces[cand, 0]]                   # (M, c, 3)
    ab = points[faces[cand, 1]] - a
    ac = points[faces[cand, 2]] - a
    ap = q[:, None, :] - a

    def dot(x, y):
        return np.einsum("mci,mci->mc", x, y)

    s, t, d2, inside = closest_params(dot(ap, ap), dot(ap, ab), dot(ap, ac), dot(ab, ab), dot(ab, ac),
                                      dot(ac, ac))
    best = np.argmin(d2, axis=1)                 # first candidate wins ties
    r = np.arange(len(q))
    return d2[r, best], s[r, best], t[r, best], inside[r, best], np.asarray(cand[r, best], dtype=np.int64)


def closest_signed_numpy(q, cand, points, faces, face_n, edge_n, edge_id, ring):
    """:func:`closest_signed` in numpy (same arguments and results)."""
    d2, s, t, inside, f = closest_candidates_numpy(q, cand, points, faces)
    a = points[faces[f, 0]]
    p = a + s[:, None] * (points[faces[f, 1]] - a) + t[:, None] * (points[faces[f, 2]] - a)
    bary = np.stack([1.0 - s - t, s, t], axis=1)
    # the closest feature as closest_feature decides it: a corner (s, t
    # clamped to 0 or 1), an edge (01, 12 or 20 of the face), or the face
    corner = np.where(t == 0, np.where(s == 0, 0, np.where(s == 1, 1, -1)),
                      np.where((s == 0) & (t == 1), 2, -1))
    edge = np.where(t == 0, 0, np.where(s == 0, 2, 1))
    corner = np.where(inside, -1, corner)
    on_edge = ~inside & (corner < 0)
    n = face_n[f].copy()
    n[on_edge] = edge_n[edge_id[f[on_edge], edge[on_edge]]]
    at = corner >= 0
    if at.any():
        n[at] = vertex_pseudo_normals_numpy(faces[f[at], corner[at]], points, faces, ring, face_n)
    side = np.einsum("ij,ij->i", np.asarray(q, dtype=np.float64) - p, n)
    return np.where(side < 0, -np.sqrt(d2), np.sqrt(d2)), p, f, bary, n


# ----------------------------------------------------------------------------
# the public kernels: compiled with numba, the numpy twin otherwise

def closest_candidates(q, cand, points, faces):
    """Closest point among candidate triangles. q (M, 3), cand (M, c)
    triangle indices, points (N, 3), faces (T, 3). Returns (squared distance
    (M,), s (M,), t (M,), inside (M,) bool, triangle (M,)): the point
    a + s (b - a) + t (c - a) of that triangle (first candidate wins ties)."""
    if not HAVE_NUMBA:
        return closest_candidates_numpy(q, cand, points, faces)
    m = len(q)
    out = (np.empty(m), np.empty(m), np.empty(m), np.empty(m, dtype=np.bool_), np.empty(m, dtype=np.int64))
    _closest_candidates(np.ascontiguousarray(q, dtype=np.float64), np.ascontiguousarray(cand, dtype=np.int64),
                        points, faces, *out)
    return out


def closest_signed(q, cand, points, faces, face_n, edge_n, edge_id, ring):
    """Signed closest point among candidate triangles. q (M, 3), cand (M, c),
    points (N, 3), faces (T, 3), face_n (T, 3) unit face normals, edge_n
    (E, 3) edge pseudo-normals, edge_id (T, 3) edges 01, 12, 20 of each face,
    ring (N, w) triangles around each vertex (padded by repeating the
    first). Returns (signed distance (M,), point (M, 3), triangle (M,),
    barycentrics (M, 3), feature pseudo-normal (M, 3), not unit)."""
    if not HAVE_NUMBA:
        return closest_signed_numpy(q, cand, points, faces, face_n, edge_n, edge_id, ring)
    m = len(q)
    out = (np.empty(m), np.empty((m, 3)), np.empty(m, dtype=np.int64), np.empty((m, 3)), np.empty((m, 3)))
    _closest_signed(np.ascontiguousarray(q, dtype=np.float64), np.ascontiguousarray(cand, dtype=np.int64),
                    points, faces, face_n, edge_n, edge_id, ring, *out)
    return out
