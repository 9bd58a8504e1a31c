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

try:  # pragma: no cover - depends on the install
    if os.environ.get("WEARFIT_NO_NUMBA"):
        raise ImportError("disabled by WEARFIT_NO_NUMBA")
    import numba
    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    numba = None
    HAVE_NUMBA = False


def _jit(fn):
    if not HAVE_NUMBA:
        return None
    return numba.njit(cache=True, nogil=True)(fn)


# ----------------------------------------------------------------------------
# binding evaluation

def _csr_times_rows3(indptr, indices, data, x, out):
    """out (M, 3) = A @ x for A in CSR (M rows) and x (K, 3)."""
    for r in range(len(indptr) - 1):
        sx = 0.0
        sy = 0.0
        sz = 0.0
        for j in range(indptr[r], indptr[r + 1]):
            c = indices[j]
            w = data[j]
            sx += w * x[c, 0]
            sy += w * x[c, 1]
            sz += w * x[c, 2]
        out[r, 0] = sx
        out[r, 1] = sy
        out[r, 2] = sz


def _binding_eval(points, used_faces, indptr, indices, data, buf, out):
    """The whole binding evaluation: body points (N, 3) and the normal
    vertices v1 + unit normal of the used triangles (U, 3) into ``buf``
    (N + U, 3), then out (M, 3) = W @ buf."""
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
    _csr_times_rows3(indptr, indices, data, buf, out)


if HAVE_NUMBA:
    _csr_times_rows3 = _jit(_csr_times_rows3)
    _binding_eval_jit = _jit(_binding_eval)
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

def _face_normals(points, faces, unit, out):
    """out (T, 3) = normals of faces (T, 3) on points (N, 3): unit (zero-area
    faces: the zero vector) or, if not ``unit``, twice the area long."""
    for f in range(faces.shape[0]):
        i0 = faces[f, 0]
        i1 = faces[f, 1]
        i2 = faces[f, 2]
        ax = points[i1, 0] - points[i0, 0]
        ay = points[i1, 1] - points[i0, 1]
        az = points[i1, 2] - points[i0, 2]
        bx = points[i2, 0] - points[i0, 0]
        by = points[i2, 1] - points[i0, 1]
        bz = points[i2, 2] - points[i0, 2]
        nx = ay * bz - az * by
        ny = az * bx - ax * bz
        nz = ax * by - ay * bx
        ln = np.sqrt(nx * nx + ny * ny + nz * nz) if unit else 1.0
        if ln < 1e-300:
            ln = 1.0
        out[f, 0] = nx / ln
        out[f, 1] = ny / ln
        out[f, 2] = nz / ln


if HAVE_NUMBA:
    _face_normals = _jit(_face_normals)


def face_normals(points: np.ndarray, faces: np.ndarray, unit: bool = True) -> np.ndarray:
    """(T, 3) face normals, unit or twice the area long; compiled (numba only)."""
    out = np.empty((len(faces), 3))
    _face_normals(np.ascontiguousarray(points, dtype=np.float64),
                  np.ascontiguousarray(faces, dtype=np.int64), bool(unit), out)
    return out


# ----------------------------------------------------------------------------
# closest point among candidate triangles

def _closest_candidates(q, cand, points, faces, out_d2, out_s, out_t, out_inside, out_tri):
    """For each query point q[i] (M, 3) the closest point on the candidate
    triangles cand[i] (M, c) of the mesh (points (N, 3), faces (T, 3)).
    Writes the squared distance, the parameters (s, t) of the closest point
    a + s (b - a) + t (c - a), whether it is inside the face, and the
    triangle. Same rules as :func:`clearance._closest_params` (first
    candidate wins ties)."""
    m, c = cand.shape
    for i in range(m):
        qx = q[i, 0]
        qy = q[i, 1]
        qz = q[i, 2]
        best = np.inf
        bs = 0.0
        bt = 0.0
        bin_ = False
        btri = cand[i, 0]
        for k in range(c):
            f = cand[i, k]
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
            if dist < best:
                best = dist
                bs = s
                bt = t
                bin_ = inside
                btri = f
        out_d2[i] = best
        out_s[i] = bs
        out_t[i] = bt
        out_inside[i] = bin_
        out_tri[i] = btri


if HAVE_NUMBA:
    _closest_candidates_jit = _jit(_closest_candidates)
else:  # pragma: no cover
    _closest_candidates_jit = None


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


# ----------------------------------------------------------------------------
# nearest vertex within a radius: a uniform grid (cell = radius)

def _grid_build(points, lo, h, dims, order, starts):
    """Counting sort of points (N, 3) into cells of size h from corner lo;
    dims (3,) cells per axis. Fills order (N,) and starts (cells + 1,)."""
    n = points.shape[0]
    d1 = dims[1]
    d2 = dims[2]
    key = np.empty(n, dtype=np.int64)
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
    fill = starts[:-1].copy()
    for i in range(n):
        k = key[i]
        order[fill[k]] = i
        fill[k] += 1


def _grid_nearest(q, points, order, starts, lo, h, dims, r2max, out_idx, out_d2):
    """Nearest point (index, squared distance) within sqrt(r2max) <= h of
    each query q (M, 3); index -1 and inf when there is none. The query's
    own cell is scanned first; a neighbouring cell only if its box is nearer
    than the best point so far."""
    d0 = dims[0]
    d1 = dims[1]
    d2 = dims[2]
    for i in range(q.shape[0]):
        qx = q[i, 0]
        qy = q[i, 1]
        qz = q[i, 2]
        fx = (qx - lo[0]) / h
        fy = (qy - lo[1]) / h
        fz = (qz - lo[2]) / h
        best = r2max
        bi = -1
        if fx > -2.0 and fy > -2.0 and fz > -2.0 and fx < d0 + 1.0 and fy < d1 + 1.0 and fz < d2 + 1.0:
            ix = int(np.floor(fx))
            iy = int(np.floor(fy))
            iz = int(np.floor(fz))
            # distances (in cells) from the query to its cell's lower/upper faces
            lx = fx - ix
            ly = fy - iy
            lz = fz - iz
            for step in range(2):  # 0: own cell, 1: the 26 neighbours
                for cx in range(max(ix - 1, 0), min(ix + 2, d0)):
                    ex = 0.0 if cx == ix else (lx if cx < ix else 1.0 - lx)
                    for cy in range(max(iy - 1, 0), min(iy + 2, d1)):
                        ey = 0.0 if cy == iy else (ly if cy < iy else 1.0 - ly)
                        base = (cx * d1 + cy) * d2
                        for cz in range(max(iz - 1, 0), min(iz + 2, d2)):
                            own = cx == ix and cy == iy and cz == iz
                            if own != (step == 0):
                                continue
                            if not own:
                                ez = 0.0 if cz == iz else (lz if cz < iz else 1.0 - lz)
                                if (ex * ex + ey * ey + ez * ez) * h * h >= best:
                                    continue
                            k = base + cz
                            for j in range(starts[k], starts[k + 1]):
                                v = order[j]
                                dx = points[v, 0] - qx
                                dy = points[v, 1] - qy
                                dz = points[v, 2] - qz
                                dd = dx * dx + dy * dy + dz * dz
                                if dd < best:
                                    best = dd
                                    bi = v
        out_idx[i] = bi
        out_d2[i] = best if bi >= 0 else np.inf


if HAVE_NUMBA:
    _grid_build = _jit(_grid_build)
    _grid_nearest = _jit(_grid_nearest)


class RadiusGrid:
    """Nearest point within a fixed radius, for points that move every frame.

    A uniform grid with cells as large as the radius: building is a counting
    sort (O(N)), a query looks at 27 cells. Compiled with numba; without it
    a KD-tree does the same job. ``RadiusGrid(points, radius).nearest(q)``
    returns (index (M,) int, -1 beyond the radius; distance (M,), inf beyond).
    """

    MAX_CELLS = 4_000_000

    def __init__(self, points: np.ndarray, radius: float):
        p = np.ascontiguousarray(points, dtype=np.float64)
        self.points, self.radius = p, float(radius)
        if not HAVE_NUMBA:  # pragma: no cover - numpy/scipy path
            from scipy.spatial import cKDTree
            self._tree = cKDTree(p)
            return
        lo = p.min(axis=0)
        span = p.max(axis=0) - lo
        h = self.radius
        while np.prod(np.floor(span / h) + 1) > self.MAX_CELLS:
            h *= 1.5  # a coarser grid stays exact (cells >= radius)
        dims = (np.floor(span / h) + 1).astype(np.int64)
        self._lo, self._h, self._dims = lo, h, dims
        self._order = np.empty(len(p), dtype=np.int64)
        self._starts = np.empty(int(np.prod(dims)) + 1, dtype=np.int64)
        _grid_build(p, lo, h, dims, self._order, self._starts)

    def nearest(self, query: np.ndarray):
        q = np.ascontiguousarray(query, dtype=np.float64)
        if not HAVE_NUMBA:  # pragma: no cover
            d, i = self._tree.query(q, k=1, distance_upper_bound=self.radius)
            i = np.where(np.isinf(d), -1, i)
            return i, d
        idx = np.empty(len(q), dtype=np.int64)
        d2 = np.empty(len(q))
        _grid_nearest(q, self.points, self._order, self._starts, self._lo, self._h, self._dims,
                      self.radius * self.radius, idx, d2)
        return idx, np.sqrt(d2)


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
    closest_candidates(pts, np.array([[0, 1]] * 4, dtype=np.int64), pts, faces)
    RadiusGrid(pts, 0.5).nearest(pts)
    import scipy.sparse as sp
    mat = sp.csr_matrix(np.ones((2, 6)))
    binding_eval(pts, faces, mat, np.zeros((6, 3)))
    return True


if __name__ == "__main__":  # python3 -m wearfit_usd.kernels: compile ahead of the first run
    print("numba kernels ready" if warm_up() else "numba not installed: numpy paths in use")
