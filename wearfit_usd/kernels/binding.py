"""Item points from body points: compiled kernels and their numpy twins.

The binding's sparse product (item = W @ [body points; normal vertices]),
whole or for a subset of rows; the per-group similarity transforms
(Umeyama) of rigid parts and their placement; the right side of the
loose-part smoothing's system; row scatters. numpy runs these as chains of
temporaries (one pass per operation over (M, c, 3) arrays); compiled, each
is one pass over the data. Each public kernel runs compiled when numba is
in use and its numpy twin (same arguments, same numbers) otherwise; the
tests check that both agree.

CSR matrices come as (indptr, indices, data) or scipy CSR; all arrays are
float64 unless stated; lengths in the units of the points.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..geometry.mesh import best_rotation
from .jit import HAVE_NUMBA, jit
from .normals import face_normals_into, face_normals_numpy


@jit(inline=True)
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


@jit
def _csr_times_rows3(indptr, indices, data, x, out):
    """out (M, 3) = A @ x for A in CSR (M rows) and x (K, 3)."""
    for r in range(len(indptr) - 1):
        out[r, 0], out[r, 1], out[r, 2] = _row_times3(indptr, indices, data, x, r)


@jit
def _fill_stacked(points, used_faces, buf):
    """buf (N + U, 3) = [body points (N, 3); normal vertices v1 + unit normal
    of the used triangles (U, 3)]: what a binding matrix multiplies. A buf of
    N + 3U rows also gets the tangent vertices v1 + t1 (U, 3) and v1 + t2
    (U, 3): t1 the unit bisector of the two edges at v1, t2 = n x t1 (an
    orthonormal frame that turns with the triangle and does not stretch with
    it)."""
    n = points.shape[0]
    nu = used_faces.shape[0]
    for i in range(n):
        buf[i, 0] = points[i, 0]
        buf[i, 1] = points[i, 1]
        buf[i, 2] = points[i, 2]
    face_normals_into(points, used_faces, True, buf[n:n + nu])
    tangents = buf.shape[0] >= n + 3 * nu
    for u in range(nu):
        i0 = used_faces[u, 0]
        if tangents:
            i1 = used_faces[u, 1]
            i2 = used_faces[u, 2]
            ax = points[i1, 0] - points[i0, 0]
            ay = points[i1, 1] - points[i0, 1]
            az = points[i1, 2] - points[i0, 2]
            la = np.sqrt(ax * ax + ay * ay + az * az)
            bx = points[i2, 0] - points[i0, 0]
            by = points[i2, 1] - points[i0, 1]
            bz = points[i2, 2] - points[i0, 2]
            lb = np.sqrt(bx * bx + by * by + bz * bz)
            if la < 1e-300:
                la = 1.0
            if lb < 1e-300:
                lb = 1.0
            ex = ax / la + bx / lb
            ey = ay / la + by / lb
            ez = az / la + bz / lb
            le = np.sqrt(ex * ex + ey * ey + ez * ez)
            if le < 1e-300:
                le = 1.0
            ex /= le
            ey /= le
            ez /= le
            nx = buf[n + u, 0]
            ny = buf[n + u, 1]
            nz = buf[n + u, 2]
            buf[n + nu + u, 0] = points[i0, 0] + ex
            buf[n + nu + u, 1] = points[i0, 1] + ey
            buf[n + nu + u, 2] = points[i0, 2] + ez
            buf[n + 2 * nu + u, 0] = points[i0, 0] + ny * ez - nz * ey
            buf[n + 2 * nu + u, 1] = points[i0, 1] + nz * ex - nx * ez
            buf[n + 2 * nu + u, 2] = points[i0, 2] + nx * ey - ny * ex
        buf[n + u, 0] += points[i0, 0]
        buf[n + u, 1] += points[i0, 1]
        buf[n + u, 2] += points[i0, 2]


@jit
def _binding_eval(points, used_faces, indptr, indices, data, buf, out):
    """The whole binding evaluation: :func:`_fill_stacked` into ``buf``,
    then out (M, 3) = W @ buf."""
    _fill_stacked(points, used_faces, buf)
    _csr_times_rows3(indptr, indices, data, buf, out)


@jit
def _binding_eval_rows(points, used_faces, indptr, indices, data, rows, buf, out):
    """:func:`_binding_eval` for a row subset of a binding matrix: row r of
    the CSR matrix (R rows) goes to out[rows[r]] (out (M, 3), other rows
    untouched)."""
    _fill_stacked(points, used_faces, buf)
    for r in range(len(indptr) - 1):
        o = rows[r]
        out[o, 0], out[o, 1], out[o, 2] = _row_times3(indptr, indices, data, buf, r)


@jit
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


@jit
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


@jit
def _diffusion_rhs(points, free, boundary, ref_free, ref_boundary, mass, indptr, indices, data, rhs):
    """rhs (U, 3) = mass (U,) * (points[free] - ref_free)
    + A @ (points[boundary] - ref_boundary) with A (U, B) in CSR: the right
    side of :class:`dress.corrections.LooseSmoother`'s system."""
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


@jit
def _add_rows(out, rows, base, delta):
    """out[rows[r]] = base[r] + delta[r] for (R, 3) base and delta."""
    for r in range(rows.shape[0]):
        o = rows[r]
        out[o, 0] = base[r, 0] + delta[r, 0]
        out[o, 1] = base[r, 1] + delta[r, 1]
        out[o, 2] = base[r, 2] + delta[r, 2]


# ----------------------------------------------------------------------------
# numpy twins (same arguments as the kernels)

def _csr(indptr, indices, data, n_cols: int) -> sp.csr_matrix:
    """The CSR matrix (len(indptr) - 1, n_cols) of these arrays (no copy)."""
    return sp.csr_matrix((data, indices, indptr), shape=(len(indptr) - 1, n_cols))


def tangent_frames_numpy(points: np.ndarray, faces: np.ndarray):
    """Unit normal n, t1 the unit bisector of the two edges at the first
    corner and t2 = n x t1 of triangles (..., T, 3) for points (..., N, 3)
    (the bisector turns about half as much as one edge under a shear)."""
    v1 = points[..., faces[:, 0], :]
    e1 = points[..., faces[:, 1], :] - v1
    e2 = points[..., faces[:, 2], :] - v1
    return frame_from_edges(e1, e2)


def frame_from_edges(e1: np.ndarray, e2: np.ndarray):
    """:func:`tangent_frames_numpy` from the edges e1 = v2 - v1, e2 = v3 - v1 (..., 3)."""
    n = np.cross(e1, e2)
    ln = np.sqrt(np.einsum("...i,...i->...", n, n))
    n = n / np.where(ln < 1e-300, 1.0, ln)[..., None]
    l1 = np.sqrt(np.einsum("...i,...i->...", e1, e1))
    l2 = np.sqrt(np.einsum("...i,...i->...", e2, e2))
    t1 = e1 / np.where(l1 < 1e-300, 1.0, l1)[..., None] + e2 / np.where(l2 < 1e-300, 1.0, l2)[..., None]
    lt = np.sqrt(np.einsum("...i,...i->...", t1, t1))
    t1 = t1 / np.where(lt < 1e-300, 1.0, lt)[..., None]
    return n, t1, np.cross(n, t1)


def fill_stacked_numpy(points: np.ndarray, used_faces: np.ndarray, buf: np.ndarray) -> None:
    """buf (N + U, 3) = [points (N, 3); v1 + unit normal of used_faces (U, 3)];
    a buf of N + 3U rows also gets v1 + t1 and v1 + t2 (see :func:`_fill_stacked`)."""
    n, nu = len(points), len(used_faces)
    buf[:n] = points
    v1 = points[used_faces[:, 0]]
    if len(buf) >= n + 3 * nu:
        nrm, t1, t2 = tangent_frames_numpy(points, used_faces)
        buf[n:n + nu] = v1 + nrm
        buf[n + nu:n + 2 * nu] = v1 + t1
        buf[n + 2 * nu:n + 3 * nu] = v1 + t2
    else:
        buf[n:n + nu] = v1 + face_normals_numpy(points, used_faces, unit=True)


def binding_eval_numpy(points: np.ndarray, used_faces: np.ndarray, matrix, buf: np.ndarray) -> np.ndarray:
    """:func:`binding_eval` in numpy: (M, 3) = matrix @ buf after
    :func:`fill_stacked_numpy`."""
    fill_stacked_numpy(points, used_faces, buf)
    return matrix @ buf


def binding_eval_rows_numpy(points, used_faces, indptr, indices, data, rows, buf, out) -> None:
    """:func:`binding_eval_rows` in numpy: out[rows] = W @ buf after
    :func:`fill_stacked_numpy` (W the CSR (R, N + U) matrix)."""
    fill_stacked_numpy(points, used_faces, buf)
    out[rows] = _csr(indptr, indices, data, len(buf)) @ buf


def similarity_transforms_numpy(points: np.ndarray, mean: sp.csr_matrix, cov: sp.csr_matrix, src_mean: np.ndarray,
                                src_var: np.ndarray, scale: bool):
    """:func:`similarity_transforms` in numpy (one batched SVD)."""
    md = mean @ points
    rot, sv = best_rotation((cov @ points).reshape(-1, 3, 3))
    if scale:
        s = sv.sum(axis=1) / np.maximum(src_var, 1e-300)
    else:
        s = np.ones(len(rot))
    t = md - s[:, None] * np.einsum("gi,gij->gj", src_mean, rot)
    return s, rot, t


def similarity_place_numpy(ref, rows, group, s, rot, t, out) -> np.ndarray:
    """:func:`similarity_place` in numpy, for any ``out``."""
    return assign_rows(out, rows, s[group, None] * np.einsum("pi,pij->pj", ref, rot[group]) + t[group])


def diffusion_rhs_numpy(points, free, boundary, ref_free, ref_boundary, mass, indptr, indices, data, rhs) -> None:
    """:func:`diffusion_rhs` in numpy."""
    rhs[:] = (mass[:, None] * (points[free] - ref_free)
              + _csr(indptr, indices, data, len(boundary)) @ (points[boundary] - ref_boundary))


def add_rows_numpy(out, rows, base, delta) -> None:
    """:func:`add_rows` in numpy."""
    out[rows] = base + delta


# ----------------------------------------------------------------------------
# the public kernels: compiled with numba, the numpy twin otherwise

#: ``binding_eval_rows(points (N, 3), used_faces (U, 3), indptr, indices,
#: data, rows (R,), buf (N + U, 3), out (M, 3))``: row r of the CSR binding
#: matrix (R rows, N + U columns) applied to [points; normal vertices of
#: used_faces] goes to out[rows[r]] (other rows untouched; buf is scratch)
binding_eval_rows = _binding_eval_rows if HAVE_NUMBA else binding_eval_rows_numpy

#: ``diffusion_rhs(points (N, 3), free (U,), boundary (B,), ref_free (U, 3),
#: ref_boundary (B, 3), mass (U,), indptr, indices, data, rhs (U, 3))``:
#: rhs = mass * (points[free] - ref_free) + A @ (points[boundary] -
#: ref_boundary), A (U, B) in CSR
diffusion_rhs = _diffusion_rhs if HAVE_NUMBA else diffusion_rhs_numpy

#: ``add_rows(out (M, 3), rows (R,), base (R, 3), delta (R, 3))``:
#: out[rows] = base + delta
add_rows = _add_rows if HAVE_NUMBA else add_rows_numpy


def binding_eval(points: np.ndarray, used_faces: np.ndarray, matrix, buf: np.ndarray) -> np.ndarray:
    """Evaluate a compact binding matrix ``matrix`` (M, N + U) CSR on body
    ``points`` (N, 3): fills ``buf`` (N + U, 3) with the points and the
    normal vertices (v1 + unit normal) of the U used triangles
    ``used_faces`` (U, 3) and returns the (M, 3) item points."""
    if not HAVE_NUMBA:
        return binding_eval_numpy(points, used_faces, matrix, buf)
    out = np.empty((matrix.shape[0], 3))
    _binding_eval(points, used_faces, matrix.indptr, matrix.indices, matrix.data, buf, out)
    return out


def similarity_transforms(points: np.ndarray, mean: sp.csr_matrix, cov: sp.csr_matrix, src_mean: np.ndarray,
                          src_var: np.ndarray, scale: bool):
    """Per group g the best-fit similarity dst ~ s src @ rot + t (Umeyama)
    of body points (N, 3), from the weighted mean (row g of ``mean`` (G, N)
    CSR) and the 3x3 cross-covariance (rows 3g..3g+2 of ``cov`` (3G, N)
    CSR); src_mean (G, 3) and src_var (G,) of the source patch. Returns
    scale (G,) (1 if not ``scale``), row-vector rotation (G, 3, 3) and
    translation (G, 3)."""
    if not HAVE_NUMBA:
        return similarity_transforms_numpy(points, mean, cov, src_mean, src_var, scale)
    g = len(src_mean)
    s, rot, t = np.empty(g), np.empty((g, 3, 3)), np.empty((g, 3))
    _similarity_transforms(np.ascontiguousarray(points, dtype=np.float64), mean.indptr, mean.indices, mean.data,
                           cov.indptr, cov.indices, cov.data, src_mean, src_var, scale, s, rot, t)
    return s, rot, t


def similarity_place(ref: np.ndarray, rows: np.ndarray, group: np.ndarray, s: np.ndarray, rot: np.ndarray,
                     t: np.ndarray, out: np.ndarray) -> np.ndarray:
    """out[rows[j]] = s[g] ref[j] @ rot[g] + t[g] with g = group[j] (rows,
    group (P,) int64; ref (P, 3); s (G,), rot (G, 3, 3) row vectors, t
    (G, 3)), in place; returns ``out`` (M, 3). Compiled for a C-contiguous
    float64 ``out``."""
    if HAVE_NUMBA and out.flags.c_contiguous and out.dtype == np.float64:
        _similarity_place(ref, rows, group, s, np.ascontiguousarray(rot), np.ascontiguousarray(t), out)
        return out
    return similarity_place_numpy(ref, rows, group, s, rot, t, out)


def assign_rows(dst: np.ndarray, idx: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``dst[idx] = values`` for (M, 3) arrays, in place; returns ``dst``.

    A C-contiguous float64 ``dst`` is viewed as one 24-byte record per row, so
    each row moves as one item: about 2x faster than numpy's fancy-index
    assignment of (P, 3) rows (per-frame smoothing and rigid parts). Plain
    numpy, no numba needed."""
    if dst.flags.c_contiguous and dst.dtype == np.float64 and dst.ndim == 2 and dst.shape[1] == 3:
        v = np.ascontiguousarray(values, dtype=np.float64)
        dst.view(_ROW3).ravel()[idx] = v.view(_ROW3).ravel()
    else:
        dst[idx] = values
    return dst


_ROW3 = np.dtype((np.void, 24))  # one (3,) float64 row
