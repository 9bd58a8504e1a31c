"""Nearest point within a radius, for points that move every frame: a
uniform grid built by counting sort, searched by compiled kernels.

:class:`RadiusGrid` is the public face; its compiled search runs when numba
is in use, and a KD-tree (scipy) is its numpy twin otherwise (the tests
check that both give the same answers). Other kernels search the grid
per point with :func:`nearest_from` on its :class:`GridArrays`.

Points (N, 3) float64; lengths in the units of the points.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from .jit import HAVE_NUMBA, jit


class GridArrays(NamedTuple):
    """The arrays of a built :class:`RadiusGrid`, as the compiled kernels
    take them (numba accepts a named tuple of arrays as one argument; a
    kernel unpacks it once, ``points, spts, order, starts, lo, h, dims =
    grid``, for :func:`nearest_from`)."""
    points: np.ndarray         # (N, 3) the points, in their own order
    sorted_points: np.ndarray  # (N, 3) points[order]: a cell's points are contiguous
    order: np.ndarray          # (N,) int64 point index of each sorted slot
    starts: np.ndarray         # (cells + 1,) int64 first slot of each cell
    lo: np.ndarray             # (3,) the grid's corner
    cell: float                # the cell size
    dims: np.ndarray           # (3,) int64 cells per axis


@jit
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


@jit
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


@jit(inline=True)
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


@jit
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


@jit(inline=True)
def nearest_from(qx, qy, qz, g, r2, points, spts, order, starts, lo, h, dims):
    """Nearest grid point within sqrt(r2) of (qx, qy, qz), the search bounded
    by point g first (-1: none): (index, squared distance), (-1, r2) if none.
    The grid's arrays come as a kernel unpacks its :class:`GridArrays` (same
    order): once, at the kernel's top (field access per query measured 3-5 %
    slower)."""
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


@jit
def _grid_nearest(q, grid, r2max, hint, out_idx, out_d2):
    """Nearest point (index, squared distance) of ``grid`` (:class:`GridArrays`)
    within sqrt(r2max) of each query q (M, 3); index -1 and inf when there is
    none. ``hint`` (M,): a point likely to be near (e.g. last frame's
    answer), -1 for none: it only bounds the search, the answer is the same."""
    points, spts, order, starts, lo, h, dims = grid
    for i in range(q.shape[0]):
        bi, best = nearest_from(q[i, 0], q[i, 1], q[i, 2], hint[i], r2max, points, spts, order, starts, lo, h, dims)
        out_idx[i] = bi
        out_d2[i] = best if bi >= 0 else np.inf


class RadiusGrid:
    """Nearest point within a fixed radius, for points that move every frame.

    A uniform grid (cells as large as the radius unless ``cell`` says
    otherwise): building is a counting sort (O(N)); a query scans its own
    cell, then only the cells nearer than the best point so far (finer cells
    measured slower on bodies: more cells to visit, fewer cache hits).
    Compiled with numba; without it a KD-tree does the same job.
    ``RadiusGrid(points, radius).nearest(q, hint=None, radius=None)``
    returns (index (M,) int, -1 beyond the radius; distance (M,), inf
    beyond); ``hint`` (M,) int, a point likely near each query (last
    frame's answer, -1 none), makes the search cheaper without changing the
    answer; ``radius`` searches farther (or nearer) than the grid's own for
    this call (a search farther than the cells visits more of them).
    :attr:`arrays` (:class:`GridArrays`, compiled path) is the built grid,
    for other kernels that search it per point (:func:`nearest_from`).
    """

    MAX_CELLS = 4_000_000

    def __init__(self, points: np.ndarray, radius: float, cell: float | None = None):
        self.radius = float(radius)
        self.cell = float(cell) if cell else self.radius
        self.arrays: GridArrays | None = None  # the built grid (compiled path)
        self._starts_buf = None
        self.update(points)

    def update(self, points: np.ndarray) -> RadiusGrid:
        """Rebuild the grid over new points (same count or not), reusing the
        buffers of the previous build (fresh arrays cost more page faults
        than the counting sort itself)."""
        p = np.ascontiguousarray(points, dtype=np.float64)
        self.points = p
        if not HAVE_NUMBA:  # pragma: no cover - numpy/scipy path
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
        a = self.arrays
        if self._starts_buf is None or len(self._starts_buf) < n_cells or len(a.order) != len(p):
            self._starts_buf = np.empty(max(n_cells, int(1.5 * n_cells)), dtype=np.int64)
            order, sorted_points = np.empty(len(p), dtype=np.int64), np.empty_like(p)
            self._key = np.empty(len(p), dtype=np.int64)
        else:
            order, sorted_points = a.order, a.sorted_points
        self.arrays = GridArrays(p, sorted_points, order, self._starts_buf[:n_cells], lo, float(h), dims)
        _grid_build(p, lo, h, dims, order, self.arrays.starts, sorted_points, self._key)
        return self

    def nearest(self, query: np.ndarray, hint: np.ndarray | None = None, radius: float | None = None):
        """Nearest point to each query (M, 3) within the radius: (index (M,),
        -1 beyond; distance (M,), inf beyond). ``hint`` (M,) int: a point
        likely near each query (-1 none); it changes only the cost.
        ``radius``: this call's radius (None: the grid's)."""
        r = self.radius if radius is None else float(radius)
        if not r > 0:
            raise ValueError(f"radius must be positive, got {radius!r}")
        q = np.ascontiguousarray(query, dtype=np.float64)
        if not HAVE_NUMBA:  # pragma: no cover
            d, i = self._tree.query(q, k=1, distance_upper_bound=r)
            i = np.where(np.isinf(d), -1, i)
            return i, d
        idx = np.empty(len(q), dtype=np.int64)
        d2 = np.empty(len(q))
        if hint is None:
            hint = np.full(len(q), -1, dtype=np.int64)
        _grid_nearest(q, self.arrays, r * r, np.ascontiguousarray(hint, dtype=np.int64), idx,
                      d2)
        return idx, np.sqrt(d2)
