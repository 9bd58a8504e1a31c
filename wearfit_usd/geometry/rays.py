"""Ray segments against triangle meshes: the coverage ray test shared by the
motion measures (:mod:`wearfit_usd.animate.measures`: coverage loss) and the
hidden body (:mod:`wearfit_usd.dress.hidden_body`)."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def ray_triangle(orig: np.ndarray, dirs: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                 t_min: float, t_max: float):
    """Two-sided ray / triangle intersection (Moller-Trumbore), row by row.

    orig, dirs (P, 3) rays (dirs unit), a, b, c (P, 3) triangle corners.
    Returns (hit (P,) bool: the ray meets the triangle at a parameter in
    [t_min, t_max], t (P,) that parameter (meaningless where not hit))."""
    e1 = b - a
    e2 = c - a
    p = np.cross(dirs, e2)
    det = np.einsum("ij,ij->i", e1, p)
    scale = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    ok = np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)
    inv = 1.0 / np.where(ok, det, 1.0)
    s = orig - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = np.einsum("ij,ij->i", dirs, q) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    tol = 1e-9
    hit = ok & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol) & (t >= t_min) & (t <= t_max)
    return hit, t


def _subdivision_centroids(n: int) -> np.ndarray:
    """Barycentric coordinates (n*n, 3) of the centroids of the n x n
    subdivision of a triangle (n*(n+1)/2 upright, n*(n-1)/2 inverted
    sub-triangles, each the triangle scaled by 1/n)."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    up = (i + j) <= n - 1
    down = (i + j) <= n - 2
    u = np.concatenate([(i[up] + 1.0 / 3.0), (i[down] + 2.0 / 3.0)]) / n
    v = np.concatenate([(j[up] + 1.0 / 3.0), (j[down] + 2.0 / 3.0)]) / n
    return np.stack([1.0 - u - v, u, v], axis=1)


def centroid_reach(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (F, 3) of triangles (F, 3, 3) and the distance (F,) from
    each centroid to its triangle's farthest corner."""
    cen = tri.mean(axis=1)
    d = tri - cen[:, None]
    return cen, np.sqrt(np.max(np.einsum("fcj,fcj->fc", d, d), axis=1))


def covering_points(tri: np.ndarray, radius: float, centres=None) -> tuple[np.ndarray, np.ndarray]:
    """Points within ``radius`` of every point of every triangle.

    A triangle whose farthest corner lies ``r`` from its centroid is
    represented by the centroids of its ``n x n`` subdivision, ``n =
    ceil(r / radius)``: each sub-triangle is the triangle scaled by ``1/n``,
    and every point of a triangle lies within its centroid-to-farthest-corner
    distance of its centroid (the distance is convex, so largest at a corner).

    Parameters
    ----------
    tri : (F, 3, 3) triangle corners.
    radius : covering radius (> 0).
    centres : :func:`centroid_reach` of ``tri`` if already known.

    Returns
    -------
    (points (S, 3), triangle of each point (S,) int).
    """
    cen, r = centroid_reach(tri) if centres is None else centres
    n = np.maximum(1, np.ceil(r / radius - 1e-9)).astype(np.int64)
    pts, owner = [cen[n == 1]], [np.flatnonzero(n == 1)]
    for k in np.unique(n[n > 1]):
        idx = np.flatnonzero(n == k)
        bary = _subdivision_centroids(int(k))
        pts.append(np.einsum("sc,fcj->fsj", bary, tri[idx]).reshape(-1, 3))
        owner.append(np.repeat(idx, len(bary)))
    return np.concatenate(pts), np.concatenate(owner)


#: rays up to which :func:`cast_rays` tests bounding boxes pair by pair
#: instead of building its KD-trees (the coverage measure re-casting the
#: rays that missed their triangle's ring): both cost in proportion to the
#: triangles, the pairs 13 ns per ray and triangle, the trees about 2.3 us per
#: triangle (measured on a 16,672-triangle suit and 3,344-triangle hair)
SMALL_RAYS = 150


def _nearest_hits(ray, cand, t, out, t_out=None):
    """out[ray] = the candidate of the nearest hit (smallest |t|) of each
    ray; t_out[ray] its t, if given."""
    order = np.lexsort((np.abs(t), ray))
    ray, cand, t = ray[order], cand[order], t[order]
    first = np.concatenate([[True], ray[1:] != ray[:-1]])
    out[ray[first]] = cand[first]
    if t_out is not None:
        t_out[ray[first]] = t[first]
    return out


def _cast_few(orig, dirs, tri, seg_lo, seg_hi, t_min, t_max, out):
    """:func:`cast_rays` for few rays x triangles: every pair whose bounding
    boxes (the segment's, seg_lo / seg_hi (R, 3), the triangle's) overlap is
    tested exactly."""
    tri_lo, tri_hi = tri.min(axis=1), tri.max(axis=1)
    ok = np.ones((len(orig), len(tri)), dtype=bool)
    for c in range(3):
        ok &= (tri_lo[None, :, c] <= seg_hi[:, None, c]) & (tri_hi[None, :, c] >= seg_lo[:, None, c])
    ray, cand = np.nonzero(ok)
    if len(ray) == 0:
        return out
    hit, t = ray_triangle(orig[ray], dirs[ray], tri[cand, 0], tri[cand, 1], tri[cand, 2], t_min, t_max)
    if hit.any():
        _nearest_hits(ray[hit], cand[hit], t[hit], out)
    return out


def cast_rays(orig: np.ndarray, dirs: np.ndarray, points: np.ndarray, faces: np.ndarray,
              t_min: float, t_max: float, chunk: int = 4096):
    """Nearest triangle of a mesh each ray segment meets.

    orig, dirs (R, 3) (dirs unit), mesh points (M, 3) and faces (F, 3);
    segments from ``orig + t_min dirs`` to ``orig + t_max dirs``.

    Candidates come from two KD-trees: the triangles are covered by points
    within a radius ``rho`` of all of their surface
    (:func:`covering_points`; ``rho`` the median triangle's
    centroid-to-corner distance, at least 1/32 of the segment), each segment
    by ``k`` evenly spaced samples within ``h <= rho`` of all of it. A
    segment meets a triangle only where a sample and a covering point lie
    within ``h + rho`` of each other; those pairs are tested exactly. The
    candidate volume is a chain of small balls along the segment, not one
    ball round its middle as wide as the segment is long. Up to
    :data:`SMALL_RAYS` rays, every ray's and triangle's bounding boxes are
    compared instead (cheaper than the trees for a few rays).

    Returns the hit triangle per ray (R,) int, -1 where none is met.
    """
    out = np.full(len(orig), -1, dtype=np.int64)
    if len(faces) == 0 or len(orig) == 0:
        return out
    orig = np.asarray(orig, dtype=np.float64)
    dirs = np.asarray(dirs, dtype=np.float64)
    tri = np.asarray(points, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    a, b = orig + dirs * t_min, orig + dirs * t_max
    seg_lo, seg_hi = np.minimum(a, b), np.maximum(a, b)
    if len(orig) <= SMALL_RAYS:
        return _cast_few(orig, dirs, tri, seg_lo, seg_hi, t_min, t_max, out)
    length = float(t_max - t_min)
    centres = centroid_reach(tri)
    rho = max(float(np.median(centres[1])), length / 32.0, 1e-9)
    cover, owner = covering_points(tri, rho, centres)
    tree = cKDTree(cover)
    k = max(1, int(np.ceil(length / (2.0 * rho))))
    h = 0.5 * length / k
    ts = t_min + (np.arange(k) + 0.5) * (length / k)
    radius = (h + rho) * (1.0 + 1e-9) + 1e-12
    n_tri = len(faces)
    # only segments whose bounding box meets the mesh's
    lo, hi = tri.min(axis=(0, 1)), tri.max(axis=(0, 1))
    near = np.flatnonzero(np.all((seg_lo <= hi) & (seg_hi >= lo), axis=1))
    for s in range(0, len(near), chunk):
        rows = near[s:s + chunk]
        samples = (orig[rows, None, :] + dirs[rows, None, :] * ts[None, :, None]).reshape(-1, 3)
        pairs = cKDTree(samples).sparse_distance_matrix(tree, radius, output_type="ndarray")
        if len(pairs) == 0:
            continue
        key = np.unique(rows[pairs["i"] // k] * n_tri + owner[pairs["j"]])
        ray, cand = key // n_tri, key % n_tri
        hit, t = ray_triangle(orig[ray], dirs[ray], tri[cand, 0], tri[cand, 1], tri[cand, 2], t_min, t_max)
        if not hit.any():
            continue
        _nearest_hits(ray[hit], cand[hit], t[hit], out)
    return out


def box_exit(origins: np.ndarray, dirs: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(R,) the distance along each ray (origins (R, 3) inside or on the
    box, dirs (R, 3) unit) to where it leaves the axis-aligned box lo..hi
    (3,): the nearest of the three slab exits (inf for a zero direction)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dirs > 0, (hi - origins) / dirs, np.where(dirs < 0, (lo - origins) / dirs, np.inf))
    return np.maximum(t.min(axis=1), 0.0)


def march_rays(orig: np.ndarray, dirs: np.ndarray, tri: np.ndarray, centroid_tree: cKDTree, t_min: float,
               t_max, reach: float | None = None, samples: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Nearest triangle each ray segment meets, marching out from its start.

    :func:`cast_rays` for segments that are long against the mesh (a ray
    followed through the body to where it leaves) or for a mesh whose
    KD-tree is already built: each segment is sampled every ``2 h`` from
    ``t_min`` on, ``samples`` at a time; a triangle whose centroid lies
    within ``h + reach`` of a sample (``reach`` the largest distance from a
    triangle's centroid to its corners) is a candidate, tested exactly. A
    ray stops at the round of its first hit, so a segment through empty
    space costs only the tree's empty lookups and one through the surface
    ends there. Every point of a round's stretch lies within ``h`` of one
    of its samples, and every point of a triangle within ``reach`` of its
    centroid: a hit is never missed, and the nearest is the first round's.

    Parameters
    ----------
    orig, dirs : (R, 3) ray origins and unit directions.
    tri : (F, 3, 3) the triangles' corners.
    centroid_tree : KD-tree over the triangles' centroids (F, 3), in order.
    t_min : where the segments start (>= 0).
    t_max : float or (R,): where each ends.
    reach : the triangles' largest centroid-to-corner distance, if known.
    samples : samples per ray and round.

    Returns
    -------
    (hit triangle (R,) int, -1 where none is met; its parameter t (R,), inf
    where none).
    """
    orig = np.asarray(orig, dtype=np.float64)
    dirs = np.asarray(dirs, dtype=np.float64)
    n_rays = len(orig)
    out = np.full(n_rays, -1, dtype=np.int64)
    t_out = np.full(n_rays, np.inf)
    if n_rays == 0 or len(tri) == 0:
        return out, t_out
    t_max = np.broadcast_to(np.asarray(t_max, dtype=np.float64), (n_rays,))
    if not np.all(np.isfinite(t_max)) or samples < 1:
        raise ValueError("march_rays needs finite segment ends and at least one sample a round")
    if reach is None:
        reach = float(centroid_reach(tri)[1].max())
    h = max(0.5 * reach, 1e-6)
    radius = (h + reach) * (1.0 + 1e-9) + 1e-12
    offsets = (np.arange(samples) + 0.5) * (2.0 * h)
    active = np.flatnonzero(t_max >= t_min)
    t0 = float(t_min)
    while len(active):
        t1 = t0 + samples * 2.0 * h
        pts = (orig[active, None, :] + dirs[active, None, :] * (t0 + offsets)[None, :, None]).reshape(-1, 3)
        pairs = cKDTree(pts).sparse_distance_matrix(centroid_tree, radius, output_type="ndarray")
        if len(pairs):
            key = np.unique(active[pairs["i"] // samples] * len(tri) + pairs["j"])
            ray, cand = key // len(tri), key % len(tri)
            hit, t = ray_triangle(orig[ray], dirs[ray], tri[cand, 0], tri[cand, 1], tri[cand, 2], t0, t1)
            hit &= t <= t_max[ray]
            if hit.any():
                _nearest_hits(ray[hit], cand[hit], t[hit], out, t_out)   # t >= t_min >= 0
        active = active[(out[active] < 0) & (t_max[active] > t1)]
        t0 = t1
    return out, t_out
