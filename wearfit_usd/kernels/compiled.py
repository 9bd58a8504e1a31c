"""Compiled inner loops for the per-frame hot paths (optional numba).

Two loops dominate an animation frame: the binding's sparse product (item =
W @ [body points; normal vertices]) and the closest-point test of item
vertices against a few candidate body triangles. numpy runs them as chains
of temporaries (one pass per operation over (M, c, 3) arrays); compiled,
each is one pass over the data. When numba is not installed (it is in the
``fast`` extra) the pure numpy versions below run instead; the tests check
that both give the same numbers.

All arrays are float64 unless stated; lengths in the units of the points.
"""
from __future__ import annotations

import os

import numpy as np

# numba's OpenMP threads (the guard's parallel loop) wait for work asleep,
# not spinning: a spinning thread takes a core from the main thread between
# frames, and on a busy machine that made animate slower than one thread
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

try:  # pragma: no cover - depends on the install
    if os.environ.get("WEARFIT_NO_NUMBA"):
        raise ImportError("disabled by WEARFIT_NO_NUMBA")
    import numba
    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    numba = None
    HAVE_NUMBA = False


def _jit(fn, parallel: bool = False, inline: bool = False):
    """numba-compile ``fn`` (cached beside the package). ``inline``: small
    helpers called per point or per grid cell are inlined into their callers
    at numba's IR level (as separate functions the search took ~30 % longer)."""
    if not HAVE_NUMBA:
        return None
    return numba.njit(cache=True, nogil=True, parallel=parallel, inline="always" if inline else "never")(fn)


# loops over independent items: threads over all cores when compiled
# (numba.prange), a plain loop otherwise
prange = numba.prange if HAVE_NUMBA else range


# ----------------------------------------------------------------------------
# binding evaluation

def _row_times3(indptr, indices, data, x, r):
    """(3,) as a tuple: row r of A in CSR times x (K, 3)."""
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for j in range(indptr[r], indptr[r + 1]):
        c = indices[j]
        w = data[j]
        sx += w * x[c, 0]
        sy += w * x[c, 1]
        sz += w * x[c, 2]
    return sx, sy, sz


def _csr_times_rows3(indptr, indices, data, x, out):
    """out (M, 3) = A @ x for A in CSR (M rows) and x (K, 3)."""
    for r in range(len(indptr) - 1):
        out[r, 0], out[r, 1], out[r, 2] = _row_times3(indptr, indices, data, x, r)


def _fill_stacked(points, used_faces, buf):
    """buf (N + U, 3) = [body points (N, 3); normal vertices v1 + unit normal
    of the used triangles (U, 3)]: what a binding matrix multiplies."""
    n = points.shape[0]
    for i in range(n):
        buf[i, 0] = points[i, 0]
        buf[i, 1] = points[i, 1]
        buf[i, 2] = points[i, 2]
    _face_normals(points, used_faces, True, buf[n:])
    for u in range(used_faces.shape[0]):
        i0 = used_faces[u, 0]
        buf[n + u, 0] += points[i0, 0]
        buf[n + u, 1] += points[i0, 1]
        buf[n + u, 2] += points[i0, 2]


def _binding_eval(points, used_faces, indptr, indices, data, buf, out):
    """The whole binding evaluation: :func:`_fill_stacked` into ``buf``,
    then out (M, 3) = W @ buf."""
    _fill_stacked(points, used_faces, buf)
    _csr_times_rows3(indptr, indices, data, buf, out)


def _binding_eval_rows(points, used_faces, indptr, indices, data, rows, buf, out):
    """:func:`_binding_eval` for a row subset of a binding matrix: row r of
    the CSR matrix (R rows) goes to out[rows[r]] (out (M, 3), other rows
    untouched)."""
    _fill_stacked(points, used_faces, buf)
    for r in range(len(indptr) - 1):
        o = rows[r]
        out[o, 0], out[o, 1], out[o, 2] = _row_times3(indptr, indices, data, buf, r)


def _similarity_place(ref, rows, group, s, rot, t, out):
    """out[rows[j]] = s[g] ref[j] @ rot[g] + t[g] with g = group[j]: rigid
    parts (ref (P, 3) their points on the reference, rot (G, 3, 3) row-vector
    rotations, s (G,), t (G, 3))."""
    for j in range(rows.shape[0]):
        g = group[j]
        x = ref[j, 0]
        y = ref[j, 1]
        z = ref[j, 2]
        o = rows[j]
        for c in range(3):
            out[o, c] = s[g] * (x * rot[g, 0, c] + y * rot[g, 1, c] + z * rot[g, 2, c]) + t[g, c]


def _similarity_transforms(points, mean_ptr, mean_idx, mean_w, cov_ptr, cov_idx, cov_w, src_mean, src_var,
                           scale, s_out, rot_out, t_out):
    """Per group g the best-fit similarity dst ~ s src @ rot + t (Umeyama)
    from the weighted mean (row g of the CSR operator ``mean``) and the 3x3
    cross-covariance (rows 3g..3g+2 of ``cov``) of points (N, 3); src_mean
    (G, 3) and src_var (G,) of the source patch. Writes s_out (G,), rot_out
    (G, 3, 3) (row vectors) and t_out (G, 3); scale False: s = 1."""
    h = np.empty((3, 3))
    for g in range(src_mean.shape[0]):
        mx, my, mz = _row_times3(mean_ptr, mean_idx, mean_w, points, g)
        for r in range(3):
            h[r, 0], h[r, 1], h[r, 2] = _row_times3(cov_ptr, cov_idx, cov_w, points, 3 * g + r)
        u, sv, vt = np.linalg.svd(h)
        d = 1.0 if np.linalg.det(u @ vt) >= 0 else -1.0
        if d < 0:
            for r in range(3):
                u[r, 2] = -u[r, 2]
        rot = u @ vt
        s = (sv[0] + sv[1] + d * sv[2]) / max(src_var[g], 1e-300) if scale else 1.0
        s_out[g] = s
        for r in range(3):
            for c in range(3):
                rot_out[g, r, c] = rot[r, c]
        t_out[g, 0] = mx - s * (src_mean[g, 0] * rot[0, 0] + src_mean[g, 1] * rot[1, 0] + src_mean[g, 2] * rot[2, 0])
        t_out[g, 1] = my - s * (src_mean[g, 0] * rot[0, 1] + src_mean[g, 1] * rot[1, 1] + src_mean[g, 2] * rot[2, 1])
        t_out[g, 2] = mz - s * (src_mean[g, 0] * rot[0, 2] + src_mean[g, 1] * rot[1, 2] + src_mean[g, 2] * rot[2, 2])


def _diffusion_rhs(points, free, boundary, ref_free, ref_boundary, mass, indptr, indices, data, rhs):
    """rhs (U, 3) = mass (U,) * (points[free] - ref_free)
    + A @ (points[boundary] - ref_boundary) with A (U, B) in CSR: the right
    side of :class:`redress.LooseSmoother`'s system."""
    for r in range(free.shape[0]):
        v = free[r]
        m = mass[r]
        sx = m * (points[v, 0] - ref_free[r, 0])
        sy = m * (points[v, 1] - ref_free[r, 1])
        sz = m * (points[v, 2] - ref_free[r, 2])
        for j in range(indptr[r], indptr[r + 1]):
            c = indices[j]
            w = data[j]
            b = boundary[c]
            sx += w * (points[b, 0] - ref_boundary[c, 0])
            sy += w * (points[b, 1] - ref_boundary[c, 1])
            sz += w * (points[b, 2] - ref_boundary[c, 2])
        rhs[r, 0] = sx
        rhs[r, 1] = sy
        rhs[r, 2] = sz


def _add_rows(out, rows, base, delta):
    """out[rows[r]] = base[r] + delta[r] for (R, 3) base and delta."""
    for r in range(rows.shape[0]):
        o = rows[r]
        out[o, 0] = base[r, 0] + delta[r, 0]
        out[o, 1] = base[r, 1] + delta[r, 1]
        out[o, 2] = base[r, 2] + delta[r, 2]


if HAVE_NUMBA:
    _row_times3 = _jit(_row_times3, inline=True)
    _csr_times_rows3 = _jit(_csr_times_rows3)
    _fill_stacked = _jit(_fill_stacked)
    _binding_eval_jit = _jit(_binding_eval)
    _binding_eval_rows = _jit(_binding_eval_rows)
    _similarity_place = _jit(_similarity_place)
    _similarity_transforms = _jit(_similarity_transforms)
    _diffusion_rhs = _jit(_diffusion_rhs)
    _add_rows = _jit(_add_rows)
else:  # pragma: no cover
    _binding_eval_jit = None


def binding_eval(points: np.ndarray, used_faces: np.ndarray, matrix, buf: np.ndarray) -> np.ndarray:
    """Evaluate a compact binding matrix ``matrix`` (M, N + U) CSR on body
    ``points`` (N, 3) (compiled; numba only, :class:`binding.Binding` keeps
    the numpy path): fills ``buf`` (N + U, 3) with the points and the normal
    vertices of the U used triangles ``used_faces`` (U, 3) and returns the
    (M, 3) item points."""
    out = np.empty((matrix.shape[0], 3))
    _binding_eval_jit(points, used_faces, matrix.indptr, matrix.indices, matrix.data, buf, out)
    return out


# ----------------------------------------------------------------------------
# triangle normals

def _corner_edges(points, a, b, c):
    """The two edges b - a and c - a leaving corner a, as six scalars."""
    return (points[b, 0] - points[a, 0], points[b, 1] - points[a, 1], points[b, 2] - points[a, 2],
            points[c, 0] - points[a, 0], points[c, 1] - points[a, 1], points[c, 2] - points[a, 2])


def _face_cross(points, faces, f):
    """(b - a) x (c - a) of triangle f = (a, b, c): its normal, twice the
    area long."""
    ax, ay, az, bx, by, bz = _corner_edges(points, faces[f, 0], faces[f, 1], faces[f, 2])
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


def _face_normals(points, faces, unit, out):
    """out (T, 3) = normals of faces (T, 3) on points (N, 3): unit (zero-area
    faces: the zero vector) or, if not ``unit``, twice the area long."""
    for f in range(faces.shape[0]):
        nx, ny, nz = _face_cross(points, faces, f)
        ln = np.sqrt(nx * nx + ny * ny + nz * nz) if unit else 1.0
        if ln < 1e-300:
            ln = 1.0
        out[f, 0] = nx / ln
        out[f, 1] = ny / ln
        out[f, 2] = nz / ln


def _vertex_normals(points, faces, out):
    """out (N, 3) = area-weighted unit vertex normals: the sum of the
    adjacent faces' cross products (faces in index order), normalised
    (zero sums stay zero)."""
    out[:] = 0.0
    for f in range(faces.shape[0]):
        nx, ny, nz = _face_cross(points, faces, f)
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


if HAVE_NUMBA:
    _corner_edges = _jit(_corner_edges, inline=True)
    _face_cross = _jit(_face_cross, inline=True)
    _face_normals = _jit(_face_normals)
    _vertex_normals = _jit(_vertex_normals)


def face_normals(points: np.ndarray, faces: np.ndarray, unit: bool = True) -> np.ndarray:
    """(T, 3) face normals, unit or twice the area long; compiled (numba only)."""
    out = np.empty((len(faces), 3))
    _face_normals(np.ascontiguousarray(points, dtype=np.float64),
                  np.ascontiguousarray(faces, dtype=np.int64), bool(unit), out)
    return out


def vertex_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) area-weighted unit vertex normals; compiled (numba only)."""
    out = np.empty((len(points), 3))
    _vertex_normals(np.ascontiguousarray(points, dtype=np.float64),
                    np.ascontiguousarray(faces, dtype=np.int64), out)
    return out


# ----------------------------------------------------------------------------
# closest point among candidate triangles

def _closest_on_triangle(qx, qy, qz, f, points, faces):
    """Closest point of triangle f to (qx, qy, qz): (squared distance, s, t,
    inside) with the point a + s (b - a) + t (c - a); same rules as
    :func:`clearance._closest_params` (plane projection inside, else the best
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


def _best_candidate(qx, qy, qz, cand, i, points, faces):
    """Closest of the triangles cand[i] (row i of (M, c)) to (qx, qy, qz):
    (squared distance, s, t, inside, triangle) as :func:`_closest_on_triangle`
    (first candidate wins ties)."""
    best = np.inf
    bs = 0.0
    bt = 0.0
    bin_ = False
    btri = cand[i, 0]
    for k in range(cand.shape[1]):
        f = cand[i, k]
        dist, s, t, inside = _closest_on_triangle(qx, qy, qz, f, points, faces)
        if dist < best:
            best = dist
            bs = s
            bt = t
            bin_ = inside
            btri = f
    return best, bs, bt, bin_, btri


def _point_on(f, s, t, points, faces):
    """The point a + s (b - a) + t (c - a) of triangle f."""
    a = faces[f, 0]
    b = faces[f, 1]
    c = faces[f, 2]
    return (points[a, 0] + s * (points[b, 0] - points[a, 0]) + t * (points[c, 0] - points[a, 0]),
            points[a, 1] + s * (points[b, 1] - points[a, 1]) + t * (points[c, 1] - points[a, 1]),
            points[a, 2] + s * (points[b, 2] - points[a, 2]) + t * (points[c, 2] - points[a, 2]))


def _closest_feature(f, s, t, inside, faces, edge_id):
    """The feature of triangle f that holds its closest point (s, t, inside
    from :func:`_closest_on_triangle`), decided as clearance._feature does:
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


def _closest_candidates(q, cand, points, faces, out_d2, out_s, out_t, out_inside, out_tri):
    """For each query point q[i] (M, 3) the closest point on the candidate
    triangles cand[i] (M, c) of the mesh (points (N, 3), faces (T, 3)).
    Writes the squared distance, the parameters (s, t) of the closest point
    a + s (b - a) + t (c - a), whether it is inside the face, and the
    triangle (first candidate wins ties)."""
    for i in range(cand.shape[0]):
        out_d2[i], out_s[i], out_t[i], out_inside[i], out_tri[i] = _best_candidate(
            q[i, 0], q[i, 1], q[i, 2], cand, i, points, faces)


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
        out_p[i, 0], out_p[i, 1], out_p[i, 2] = _point_on(f, s, t, points, faces)
        out_bary[i, 0] = 1.0 - s - t
        out_bary[i, 1] = s
        out_bary[i, 2] = t
        out_tri[i] = f
        e, v = _closest_feature(f, s, t, inside, faces, edge_id)
        if e >= 0:
            nx, ny, nz = edge_n[e, 0], edge_n[e, 1], edge_n[e, 2]
        elif v >= 0:
            nx, ny, nz = _vertex_pseudo_normal(v, points, faces, ring, face_n)
        else:
            nx, ny, nz = face_n[f, 0], face_n[f, 1], face_n[f, 2]
        out_n[i, 0] = nx
        out_n[i, 1] = ny
        out_n[i, 2] = nz
        side = (q[i, 0] - out_p[i, 0]) * nx + (q[i, 1] - out_p[i, 1]) * ny + (q[i, 2] - out_p[i, 2]) * nz
        out_d[i] = -np.sqrt(best) if side < 0 else np.sqrt(best)


if HAVE_NUMBA:
    _closest_on_triangle = _jit(_closest_on_triangle)
    _best_candidate = _jit(_best_candidate, inline=True)
    _point_on = _jit(_point_on, inline=True)
    _closest_feature = _jit(_closest_feature, inline=True)
    _closest_candidates_jit = _jit(_closest_candidates)
    _closest_signed_jit = _jit(_closest_signed)
else:  # pragma: no cover
    _closest_candidates_jit = None
    _closest_signed_jit = None


def closest_candidates(q, cand, points, faces):
    """Closest point among candidate triangles (compiled; numba only, the
    callers keep a numpy path). q (M, 3), cand (M, c) triangle indices,
    points (N, 3), faces (T, 3). Returns (squared distance (M,), s (M,),
    t (M,), inside (M,) bool, triangle (M,))."""
    m = len(q)
    out = (np.empty(m), np.empty(m), np.empty(m), np.empty(m, dtype=np.bool_), np.empty(m, dtype=np.int64))
    _closest_candidates_jit(np.ascontiguousarray(q, dtype=np.float64), np.ascontiguousarray(cand, dtype=np.int64),
                            points, faces, *out)
    return out


def closest_signed(q, cand, points, faces, face_n, edge_n, edge_id, ring):
    """Signed closest point among candidate triangles (compiled; numba
    only). q (M, 3), cand (M, c), points (N, 3), faces (T, 3), face_n (T, 3)
    unit face normals, edge_n (E, 3) edge pseudo-normals, edge_id (T, 3)
    edges 01, 12, 20 of each face, ring (N, w) triangles around each vertex
    (padded by repeating the first). Returns (signed distance (M,), point
    (M, 3), triangle (M,), barycentrics (M, 3), feature pseudo-normal (M, 3),
    not unit)."""
    m = len(q)
    out = (np.empty(m), np.empty((m, 3)), np.empty(m, dtype=np.int64), np.empty((m, 3)), np.empty((m, 3)))
    _closest_signed_jit(np.ascontiguousarray(q, dtype=np.float64), np.ascontiguousarray(cand, dtype=np.int64),
                        points, faces, face_n, edge_n, edge_id, ring, *out)
    return out


# ----------------------------------------------------------------------------
# nearest vertex within a radius: a uniform grid

def _bounds(points, lo, hi):
    """Per-axis minimum lo (3,) and maximum hi (3,) of points (N, 3), N > 0."""
    for j in range(3):
        lo[j] = points[0, j]
        hi[j] = points[0, j]
    for i in range(1, points.shape[0]):
        for j in range(3):
            x = points[i, j]
            if x < lo[j]:
                lo[j] = x
            elif x > hi[j]:
                hi[j] = x


def _grid_build(points, lo, h, dims, order, starts, sorted_points, key):
    """Counting sort of points (N, 3) into cells of size h from corner lo;
    dims (3,) cells per axis. Fills order (N,), starts (cells + 1,) and
    sorted_points (N, 3) = points[order] (a cell's points are contiguous);
    key (N,) int64 is scratch."""
    n = points.shape[0]
    d1 = dims[1]
    d2 = dims[2]
    starts[:] = 0
    for i in range(n):
        ix = int((points[i, 0] - lo[0]) / h)
        iy = int((points[i, 1] - lo[1]) / h)
        iz = int((points[i, 2] - lo[2]) / h)
        k = (ix * d1 + iy) * d2 + iz
        key[i] = k
        starts[k + 1] += 1
    for k in range(1, starts.shape[0]):
        starts[k] += starts[k - 1]
    for i in range(n):  # key[i] becomes the slot of point i
        k = key[i]
        j = starts[k]
        starts[k] = j + 1
        key[i] = j
    for k in range(starts.shape[0] - 1, 0, -1):  # shift back: starts[k] = first slot of cell k
        starts[k] = starts[k - 1]
    starts[0] = 0
    for i in range(n):
        j = key[i]
        order[j] = i
        sorted_points[j, 0] = points[i, 0]
        sorted_points[j, 1] = points[i, 1]
        sorted_points[j, 2] = points[i, 2]


def _scan_cell(qx, qy, qz, k, best, bi, spts, order, starts):
    """The points of grid cell k nearer to (qx, qy, qz) than sqrt(best):
    returns the nearest (index, squared distance), (bi, best) if none."""
    for j in range(starts[k], starts[k + 1]):
        dx = spts[j, 0] - qx
        dy = spts[j, 1] - qy
        dz = spts[j, 2] - qz
        dd = dx * dx + dy * dy + dz * dz
        if dd < best:
            best = dd
            bi = order[j]
    return bi, best


def _grid_scan(qx, qy, qz, best, bi, spts, order, starts, lo, h, dims):
    """Nearest grid point to (qx, qy, qz) strictly closer than sqrt(best),
    starting from the candidate ``bi`` (-1: none) at squared distance
    ``best`` (spts (N, 3): the points in cell order): the query's own cell first, then the cells the sphere of
    radius sqrt(best) overlaps (shrinking as better points are found),
    skipping those whose box is not nearer than the best point so far.
    Returns (index, squared distance)."""
    d0 = dims[0]
    d1 = dims[1]
    d2 = dims[2]
    fx = (qx - lo[0]) / h
    fy = (qy - lo[1]) / h
    fz = (qz - lo[2]) / h
    ix = int(np.floor(fx))
    iy = int(np.floor(fy))
    iz = int(np.floor(fz))
    own = ix >= 0 and iy >= 0 and iz >= 0 and ix < d0 and iy < d1 and iz < d2
    if own:
        k = (ix * d1 + iy) * d2 + iz
        bi, best = _scan_cell(qx, qy, qz, k, best, bi, spts, order, starts)
    reach = np.sqrt(best) / h
    x0 = max(int(np.floor(fx - reach)), 0)
    x1 = min(int(np.floor(fx + reach)), d0 - 1)
    y0 = max(int(np.floor(fy - reach)), 0)
    y1 = min(int(np.floor(fy + reach)), d1 - 1)
    z0 = max(int(np.floor(fz - reach)), 0)
    z1 = min(int(np.floor(fz + reach)), d2 - 1)
    h2 = h * h
    for cx in range(x0, x1 + 1):
        ex = max(cx - fx, 0.0, fx - cx - 1.0)
        for cy in range(y0, y1 + 1):
            ey = max(cy - fy, 0.0, fy - cy - 1.0)
            exy = ex * ex + ey * ey
            if exy * h2 >= best:
                continue
            base = (cx * d1 + cy) * d2
            for cz in range(z0, z1 + 1):
                if own and cx == ix and cy == iy and cz == iz:
                    continue
                ez = max(cz - fz, 0.0, fz - cz - 1.0)
                if (exy + ez * ez) * h2 >= best:
                    continue
                bi, best = _scan_cell(qx, qy, qz, base + cz, best, bi, spts, order, starts)
    return bi, best


def _nearest_from(qx, qy, qz, g, r2, spts, order, starts, lo, h, dims, points):
    """Nearest point within sqrt(r2) of (qx, qy, qz), the search bounded by
    point g first (-1: none): (index, squared distance), (-1, r2) if none."""
    best = r2
    bi = -1
    if g >= 0:
        dx = points[g, 0] - qx
        dy = points[g, 1] - qy
        dz = points[g, 2] - qz
        dd = dx * dx + dy * dy + dz * dz
        if dd < best:
            best = dd
            bi = g
    return _grid_scan(qx, qy, qz, best, bi, spts, order, starts, lo, h, dims)


def _grid_nearest(q, points, spts, order, starts, lo, h, dims, r2max, hint, out_idx, out_d2):
    """Nearest point (index, squared distance) within sqrt(r2max) of each
    query q (M, 3); index -1 and inf when there is none. ``hint`` (M,): a
    point likely to be near (e.g. last frame's answer), -1 for none: it only
    bounds the search, the answer is the same."""
    for i in range(q.shape[0]):
        bi, best = _nearest_from(q[i, 0], q[i, 1], q[i, 2], hint[i], r2max, spts, order, starts, lo, h, dims,
                                 points)
        out_idx[i] = bi
        out_d2[i] = best if bi >= 0 else np.inf


if HAVE_NUMBA:
    _bounds = _jit(_bounds)
    _grid_build = _jit(_grid_build)
    _scan_cell = _jit(_scan_cell, inline=True)
    _grid_scan = _jit(_grid_scan)
    _nearest_from = _jit(_nearest_from, inline=True)
    _grid_nearest = _jit(_grid_nearest)


class RadiusGrid:
    """Nearest point within a fixed radius, for points that move every frame.

    A uniform grid (cells as large as the radius unless ``cell`` says
    otherwise): building is a counting sort (O(N)); a query scans its own
    cell, then only the cells nearer than the best point so far (finer cells
    measured slower on bodies: more cells to visit, fewer cache hits). Compiled with numba; without it a KD-tree does the
    same job. ``RadiusGrid(points, radius).nearest(q, hint=None)`` returns
    (index (M,) int, -1 beyond the radius; distance (M,), inf beyond);
    ``hint`` (M,) int, a point likely near each query (last frame's answer,
    -1 none), makes the search cheaper without changing the answer.
    """

    MAX_CELLS = 4_000_000

    def __init__(self, points: np.ndarray, radius: float, cell: float | None = None):
        self.radius = float(radius)
        self.cell = float(cell) if cell else self.radius
        self._starts_buf = None
        self.update(points)

    def update(self, points: np.ndarray) -> "RadiusGrid":
        """Rebuild the grid over new points (same count or not), reusing the
        buffers of the previous build (fresh arrays cost more page faults
        than the counting sort itself)."""
        p = np.ascontiguousarray(points, dtype=np.float64)
        self.points = p
        if not HAVE_NUMBA:  # pragma: no cover - numpy/scipy path
            from scipy.spatial import cKDTree
            self._tree = cKDTree(p)
            return self
        lo, hi = np.empty(3), np.empty(3)
        _bounds(p, lo, hi)  # numpy's p.min(axis=0) on (N, 3) costs ~0.5 ms per 13k points
        span = hi - lo
        h = self.cell
        while np.prod(np.floor(span / h) + 1) > self.MAX_CELLS:
            h *= 1.5  # a coarser grid only costs time
        dims = (np.floor(span / h) + 1).astype(np.int64)
        n_cells = int(np.prod(dims)) + 1
        if self._starts_buf is None or len(self._starts_buf) < n_cells or len(self._order) != len(p):
            self._starts_buf = np.empty(max(n_cells, int(1.5 * n_cells)), dtype=np.int64)
            self._order = np.empty(len(p), dtype=np.int64)
            self._key = np.empty(len(p), dtype=np.int64)
            self._sorted = np.empty_like(p)
        self._lo, self._h, self._dims = lo, h, dims
        self._starts = self._starts_buf[:n_cells]
        _grid_build(p, lo, h, dims, self._order, self._starts, self._sorted, self._key)
        return self

    def nearest(self, query: np.ndarray, hint: np.ndarray | None = None):
        q = np.ascontiguousarray(query, dtype=np.float64)
        if not HAVE_NUMBA:  # pragma: no cover
            d, i = self._tree.query(q, k=1, distance_upper_bound=self.radius)
            i = np.where(np.isinf(d), -1, i)
            return i, d
        idx = np.empty(len(q), dtype=np.int64)
        d2 = np.empty(len(q))
        if hint is None:
            hint = np.full(len(q), -1, dtype=np.int64)
        _grid_nearest(q, self.points, self._sorted, self._order, self._starts, self._lo, self._h, self._dims,
                      self.radius * self.radius, np.ascontiguousarray(hint, dtype=np.int64), idx, d2)
        return idx, np.sqrt(d2)


# ----------------------------------------------------------------------------
# the per-frame penetration guard (penetration_guard.PenetrationGuard)

def _body_normals(faces, face_n, vsum):
    """Per-vertex sums vsum (N, 3) of the adjacent faces' unit normals face_n
    (T, 3), faces added in index order (as clearance.py's sparse incidence
    product does)."""
    vsum[:] = 0.0
    for f in range(faces.shape[0]):
        for k in range(3):
            v = faces[f, k]
            vsum[v, 0] += face_n[f, 0]
            vsum[v, 1] += face_n[f, 1]
            vsum[v, 2] += face_n[f, 2]


def _vertex_pseudo_normal(v, points, faces, ring, face_n):
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
            e1x, e1y, e1z, e2x, e2y, e2z = _corner_edges(points, faces[f, c], faces[f, (c + 1) % 3],
                                                         faces[f, (c + 2) % 3])
            ln = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z) * np.sqrt(e2x * e2x + e2y * e2y + e2z * e2z)
            cosang = (e1x * e2x + e1y * e2y + e1z * e2z) / max(ln, 1e-300)
            ang = np.arccos(min(max(cosang, -1.0), 1.0))
            nx += face_n[f, 0] * ang
            ny += face_n[f, 1] * ang
            nz += face_n[f, 2] * ang
    return nx, ny, nz


def _vertex_estimate(px, py, pz, bi, points, vsum):
    """Offset of (px, py, pz) along the unit normal sum of vertex bi."""
    nx = vsum[bi, 0]
    ny = vsum[bi, 1]
    nz = vsum[bi, 2]
    ln = max(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
    return ((px - points[bi, 0]) * nx + (py - points[bi, 1]) * ny + (pz - points[bi, 2]) * nz) / ln


def _guard_estimate(q, hint, points, vsum, spts, order, starts, lo, h, dims, r2, out_est, out_vi):
    """Clearance estimate of each q (M, 3) through its nearest body vertex
    within sqrt(r2) (grid search from ``hint``): offset along that vertex's
    normal, +inf (vertex 0) when none is that near."""
    for i in range(q.shape[0]):
        qx = q[i, 0]
        qy = q[i, 1]
        qz = q[i, 2]
        bi, _ = _nearest_from(qx, qy, qz, hint[i], r2, spts, order, starts, lo, h, dims, points)
        if bi < 0:
            out_est[i] = np.inf
            out_vi[i] = 0
        else:
            out_est[i] = _vertex_estimate(qx, qy, qz, bi, points, vsum)
            out_vi[i] = bi


def _exact_signed(ix, iy, iz, i, near, cand0, ring, points, faces, edge_id, face_n, edge_faces):
    """Signed distance of (ix, iy, iz) to the closest of the triangles
    cand0[i] and ring[near] (first wins ties), sign and normal (not unit)
    from the closest feature's pseudo-normal, as clearance.SurfaceQuery
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
        dist, s, t, inside = _closest_on_triangle(ix, iy, iz, f, points, faces)
        if dist < bd:
            bd = dist
            bs = s
            bt = t
            bin_ = inside
            btri = f
    cx, cy, cz = _point_on(btri, bs, bt, points, faces)
    e, v = _closest_feature(btri, bs, bt, bin_, faces, edge_id)
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
        nx, ny, nz = _vertex_pseudo_normal(v, points, faces, ring, face_n)
    else:
        nx = face_n[btri, 0]
        ny = face_n[btri, 1]
        nz = face_n[btri, 2]
    sd = np.sqrt(bd)
    if (ix - cx) * nx + (iy - cy) * ny + (iz - cz) * nz < 0:
        sd = -sd
    return sd, nx, ny, nz


def _guard_frame(item, push, direction, hint, cand0, approx0, outside0, target, decay, margin, drop,
                 points, faces, edge_id, ring, face_n, edge_faces, vsum,
                 spts, order, starts, lo, h, dims, r2, out):
    """One frame of :meth:`penetration_guard.PenetrationGuard.apply` for all
    item vertices item (M, 3): decays push (M,) (direction (M, 3)), finds the
    suspects by the nearest-vertex estimate (hint (M,): last frame's nearest
    vertex, updated), gives them the exact signed distance among their
    frame-0 triangles cand0 (M, c) and the ring of the body vertex nearest
    to them, pushes them out to target (M,), and checks the pushed point the
    same way: one still within ``margin`` of the surface (pushed into another
    body part, or a wrong first normal) gets a second push from there, the
    two combined into one displacement. Writes out (M, 3); returns the number
    of suspects inside by more than ``margin`` before correction. Runs on
    all cores (1.7x faster on 2 cores for the 12,661 vertices of ref_male's
    items; the same numbers as one thread)."""
    n_inside = 0
    for i in prange(item.shape[0]):  # every i touches only row i of the state arrays
        p = push[i] * decay
        ix = item[i, 0]
        iy = item[i, 1]
        iz = item[i, 2]
        px = ix + p * direction[i, 0]
        py = iy + p * direction[i, 1]
        pz = iz + p * direction[i, 2]
        bi, _ = _nearest_from(px, py, pz, hint[i], r2, spts, order, starts, lo, h, dims, points)
        hint[i] = bi
        if bi >= 0 and outside0[i]:
            est = _vertex_estimate(px, py, pz, bi, points, vsum)
            if est < approx0[i] - drop or est < margin:
                # the body vertex nearest to the item vertex before any push
                near, _ = _nearest_from(ix, iy, iz, bi, r2, spts, order, starts, lo, h, dims, points)
                if near < 0:
                    near = bi
                sd, nx, ny, nz = _exact_signed(ix, iy, iz, i, near, cand0, ring, points, faces, edge_id,
                                               face_n, edge_faces)
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
                    near2, _ = _nearest_from(qx, qy, qz, near, r2, spts, order, starts, lo, h, dims, points)
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


if HAVE_NUMBA:
    _body_normals = _jit(_body_normals)
    _vertex_pseudo_normal = _jit(_vertex_pseudo_normal)
    _vertex_estimate = _jit(_vertex_estimate)
    _guard_estimate = _jit(_guard_estimate)
    _exact_signed = _jit(_exact_signed)
    _guard_frame = _jit(_guard_frame, parallel=True)


# ----------------------------------------------------------------------------
# row scatter

def assign_rows(dst: np.ndarray, idx: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``dst[idx] = values`` for (M, 3) arrays, in place; returns ``dst``.

    A C-contiguous float64 ``dst`` is viewed as one 24-byte record per row, so
    each row moves as one item: about 2x faster than numpy's fancy-index
    assignment of (P, 3) rows (per-frame smoothing and rigid parts)."""
    if dst.flags.c_contiguous and dst.dtype == np.float64 and dst.ndim == 2 and dst.shape[1] == 3:
        v = np.ascontiguousarray(values, dtype=np.float64)
        dst.view(_ROW3).ravel()[idx] = v.view(_ROW3).ravel()
    else:
        dst[idx] = values
    return dst


_ROW3 = np.dtype((np.void, 24))  # one (3,) float64 row


def warm_up() -> bool:
    """Compile (or load from numba's cache) every kernel on tiny inputs, so
    the first real call does not pay the compilation; install.sh runs this.
    Returns whether numba is in use."""
    if not HAVE_NUMBA:
        return False
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    face_normals(pts, faces)
    vertex_normals(pts, faces)
    closest_candidates(pts, np.array([[0, 1]] * 4, dtype=np.int64), pts, faces)
    RadiusGrid(pts, 0.5).nearest(pts)
    from ..animate.penetration_guard import PenetrationGuard
    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], dtype=np.int64)
    probe = np.array([[0.2, 0.2, 0.2], [0.0, 0.0, -0.1]])
    guard = PenetrationGuard(tet, pts, probe)
    guard.apply(pts * 1.5, probe)
    import scipy.sparse as sp
    mat = sp.csr_matrix(np.ones((2, 6)))
    binding_eval(pts, faces, mat, np.zeros((6, 3)))
    # the per-frame plan evaluation (frame_eval.FrameEvaluator), with the
    # index dtypes it meets: int32 CSR indices, int64 vertex rows
    out = np.zeros((2, 3))
    rows = np.arange(2, dtype=np.int64)
    _binding_eval_rows(pts, faces, mat.indptr, mat.indices, mat.data, rows, np.zeros((6, 3)), out)
    _similarity_place(pts[:2], rows, np.zeros(2, dtype=np.int64), np.ones(1), np.eye(3)[None], np.zeros((1, 3)),
                      out)
    cov = sp.csr_matrix(np.ones((3, 4)))
    mean = sp.csr_matrix(np.full((1, 4), 0.25))
    _similarity_transforms(pts, mean.indptr, mean.indices, mean.data, cov.indptr, cov.indices, cov.data,
                           np.zeros((1, 3)), np.ones(1), True, np.empty(1), np.empty((1, 3, 3)), np.empty((1, 3)))
    lap = sp.csr_matrix(np.ones((2, 1)))
    _diffusion_rhs(pts, rows, np.zeros(1, dtype=np.int64), out, out[:1], np.ones(2), lap.indptr, lap.indices,
                   lap.data, np.empty((2, 3)))
    _add_rows(out, rows, out.copy(), out.copy())
    return True


if __name__ == "__main__":  # python3 -m wearfit_usd.kernels: compile ahead of the first run
    print("numba kernels ready" if warm_up() else "numba not installed: numpy paths in use")
