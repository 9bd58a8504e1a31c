"""Smooth implicit solids and a vectorised surface-nets mesher (numpy only).

A solid is a smooth union of *round cones* (the convex hull of two spheres)
evaluated in an anisotropically scaled local frame, which also gives
ellipsoids (``a == b``) and flattened limbs (hands, feet). Each primitive
value is scaled so that it is 1-Lipschitz and zero on its own surface, and
the polynomial smooth minimum keeps that property; hence
``f(p) <= distance(p, surface)`` outside: a point with ``f(p) >= c`` is at
least ``c`` metres outside the solid. Items rely on this for their clearance.

Units are metres; points are (N, 3) arrays in internal space (Y up).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp


@dataclass
class Primitive:
    """Round cone from ``a`` (radius ``ra``) to ``b`` (radius ``rb``).

    ``frame`` (3, 3): rows are orthonormal axes of the local frame; ``scale``
    (3,): the cone is stretched by ``scale[i]`` along ``frame[i]`` about
    ``a`` (cross sections become ellipses). ``bone`` names the skeleton joint
    that owns the primitive (for skin weights and labels).
    """
    a: np.ndarray
    b: np.ndarray
    ra: float
    rb: float
    bone: str
    frame: np.ndarray = field(default_factory=lambda: np.eye(3))
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    blend: float | None = None  # smooth-union radius (m); None = the solid's default

    def bounds(self, margin: float) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned box (lo, hi) holding the primitive grown by ``margin``."""
        ext = np.abs(self.frame * self.scale[:, None]).sum(axis=0) * max(self.ra, self.rb)
        lo = np.minimum(self.a, self.b) - ext - margin
        hi = np.maximum(self.a, self.b) + ext + margin
        return lo, hi

    def _setup(self):
        s = np.asarray(self.scale, float)
        self._m = np.ascontiguousarray(self.frame.T / s)  # world offset -> scaled local
        tip = (self.b - self.a) @ self._m
        self._len = float(np.linalg.norm(tip))
        self._u = tip / self._len if self._len > 1e-9 else np.zeros(3)
        sin_a = (self.ra - self.rb) / self._len if self._len > 1e-9 else 0.0
        self._sin, self._cos = sin_a, float(np.sqrt(max(1.0 - sin_a * sin_a, 0.0)))
        self._k = float(s.min())

    def evaluate(self, p: np.ndarray) -> np.ndarray:
        """(M, 3) points -> (M,) 1-Lipschitz lower bound of the signed distance."""
        if not hasattr(self, "_m"):
            self._setup()
        q = (p - self.a) @ self._m
        q2 = np.einsum("ij,ij->i", q, q)
        if self._len < 1e-9:  # sphere (ellipsoid after scaling)
            return (np.sqrt(q2) - self.ra) * self._k
        t = q @ self._u
        rho = np.sqrt(np.maximum(q2 - t * t, 0.0))
        L, sa, ca = self._len, self._sin, self._cos
        # (t, rho) half plane: cap 1 before the first tangent point, cap 2 after
        # the second, the cone side in between
        d = t * sa + rho * ca - self.ra
        cap1 = t * ca - rho * sa < 0
        cap2 = (t - L) * ca - rho * sa > 0
        if cap1.any():
            d[cap1] = np.sqrt(q2[cap1]) - self.ra
        if cap2.any():
            tl = t[cap2] - L
            d[cap2] = np.sqrt(tl * tl + rho[cap2] ** 2) - self.rb
        return d * self._k


def smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum (a convex blend of gradients: stays 1-Lipschitz)."""
    if k <= 0:
        return np.minimum(a, b)
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - h * h * k * 0.25


class Solid:
    """Smooth union of primitives. ``solid(points)`` -> (M,) values.

    Values are exact up to ``band`` metres; farther points return ``band``
    (a valid lower bound), which keeps evaluation local and fast.
    """

    def __init__(self, primitives: list[Primitive], blend: float = 0.025, band: float = 0.1):
        self.primitives = primitives
        self.blend = blend
        self.band = band
        self._boxes = []
        for pr in primitives:
            k = self.blend if pr.blend is None else pr.blend
            ratio = float(pr.scale.max() / pr.scale.min())
            self._boxes.append(pr.bounds((band + k) * ratio))

    def bones(self) -> list[str]:
        return [p.bone for p in self.primitives]

    def candidates(self, points: np.ndarray, slack: float = 0.0):
        """[(primitive index, point indices)] of the primitives whose box
        (grown by ``slack``) holds each point; reusable while points move
        less than ``slack``."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        cols = [np.ascontiguousarray(p[:, i]) for i in range(3)]
        out = []
        for i, (lo, hi) in enumerate(self._boxes):
            m = (cols[0] >= lo[0] - slack) & (cols[0] <= hi[0] + slack)
            m &= (cols[1] >= lo[1] - slack) & (cols[1] <= hi[1] + slack)
            m &= (cols[2] >= lo[2] - slack) & (cols[2] <= hi[2] + slack)
            idx = np.flatnonzero(m)
            if len(idx):
                out.append((i, idx))
        return out

    def __call__(self, points: np.ndarray, cand=None) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if cand is None:
            cand = self.candidates(p)
        acc = np.full(len(p), 1e3)
        for i, idx in cand:
            pr = self.primitives[i]
            k = self.blend if pr.blend is None else pr.blend
            acc[idx] = smooth_min(acc[idx], pr.evaluate(p[idx]), k)
        return np.minimum(acc, self.band)

    def labels(self, points: np.ndarray) -> np.ndarray:
        """(M,) index of the primitive with the lowest value at each point."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        best = np.full(len(p), np.inf)
        lab = np.zeros(len(p), dtype=np.int64)
        for i, idx in self.candidates(p):
            d = self.primitives[i].evaluate(p[idx])
            better = d < best[idx]
            best[idx[better]] = d[better]
            lab[idx[better]] = i
        return lab

    def value_and_gradient(self, points: np.ndarray, cand=None, eps: float = 1e-4):
        """(M,) values and (M, 3) forward-difference gradients."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if cand is None:
            cand = self.candidates(p, slack=eps)
        f = self(p, cand)
        g = np.empty_like(p)
        for ax in range(3):
            q = p.copy()
            q[:, ax] += eps
            g[:, ax] = (self(q, cand) - f) / eps
        return f, g

    def gradient(self, points: np.ndarray, eps: float = 1e-4) -> np.ndarray:
        return self.value_and_gradient(points, eps=eps)[1]

    def project(self, points: np.ndarray, level: float = 0.0, iters: int = 6,
                max_step: float = 0.03) -> np.ndarray:
        """Move points onto the level set ``f = level`` by Newton steps along
        the gradient (for points within the band)."""
        p = np.array(points, dtype=np.float64).reshape(-1, 3)
        cand = self.candidates(p, slack=0.02)
        for _ in range(iters):
            f, g = self.value_and_gradient(p, cand)
            g2 = np.maximum(np.sum(g * g, axis=1), 1e-6)
            step = np.clip((f - level) / g2, -max_step, max_step)
            p -= step[:, None] * g
        return p

    def push_out(self, points: np.ndarray, directions: np.ndarray, level: float,
                 step: float = 0.002, max_dist: float = 0.3) -> np.ndarray:
        """Move each point along its (unit) direction to the first position
        where ``f >= level`` (points already there stay). Marches in
        ``step`` metres, then refines by bisection."""
        p = np.asarray(points, dtype=np.float64)
        d = np.asarray(directions, dtype=np.float64)
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        n = len(p)
        t = np.zeros(n)
        todo = np.flatnonzero(self(p) < level)
        lo = np.zeros(n)
        while len(todo) and t[todo].max() < max_dist:
            lo[todo] = t[todo]
            t[todo] += step
            ok = self(p[todo] + t[todo, None] * d[todo]) >= level
            todo = todo[~ok]
        moved = t > 0
        a, b = lo[moved], t[moved]
        pm, dm = p[moved], d[moved]
        for _ in range(8):
            mid = 0.5 * (a + b)
            ok = self(pm + mid[:, None] * dm) >= level
            b = np.where(ok, mid, b)
            a = np.where(ok, a, mid)
        out = p.copy()
        out[moved] = pm + b[:, None] * dm
        return out


# --------------------------------------------------------------------------
# surface nets

def sample_grid(solid: Solid, lo: np.ndarray, hi: np.ndarray, h: float, band: float | None = None):
    """Values of ``solid`` on a regular grid. Returns (values (nx, ny, nz),
    origin (3,), h). Each primitive is evaluated on the sub-block of its box
    only, with a narrow band (default 3 cells) since only signs near the
    surface matter. Exact zeros are nudged so every edge has a clear sign."""
    lo = np.asarray(lo, float)
    n = np.ceil((np.asarray(hi, float) - lo) / h).astype(int) + 1
    band = 3 * h if band is None else band
    narrow = Solid(solid.primitives, solid.blend, band)
    vals = np.full(tuple(n), 1e3)
    for pr, (blo, bhi) in zip(narrow.primitives, narrow._boxes):
        i0 = np.clip(np.floor((blo - lo) / h).astype(int), 0, n)
        i1 = np.clip(np.ceil((bhi - lo) / h).astype(int) + 1, 0, n)
        if np.any(i1 <= i0):
            continue
        axes = [lo[i] + h * np.arange(i0[i], i1[i]) for i in range(3)]
        gx, gy, gz = np.meshgrid(*axes, indexing="ij")
        pts = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
        k = narrow.blend if pr.blend is None else pr.blend
        block = vals[i0[0]:i1[0], i0[1]:i1[1], i0[2]:i1[2]]
        block[...] = smooth_min(block, pr.evaluate(pts).reshape(block.shape), k)
    vals = np.minimum(vals, band)
    vals[vals == 0.0] = 1e-9
    resolve_ambiguous_faces(vals)
    return vals, lo, h


def resolve_ambiguous_faces(vals: np.ndarray, max_rounds: int = 6) -> int:
    """Make the sign pattern unambiguous for surface nets, in place.

    A grid face whose corners alternate inside/outside (+-+-) would give an
    edge shared by four quads. Such faces only occur where the solid is
    about one cell thin; their outside corners are moved just inside (a
    sub-cell thickening), repeated until none is left. Returns the number
    of corners changed."""
    changed = 0
    for _ in range(max_rounds):
        ins = vals < 0
        fix = np.zeros_like(ins)
        for ax in range(3):
            b, c = (ax + 1) % 3, (ax + 2) % 3

            def sl(db, dc, b=b, c=c, ins=ins):
                s = [slice(None)] * 3
                s[b] = slice(db, ins.shape[b] - 1 + db)
                s[c] = slice(dc, ins.shape[c] - 1 + dc)
                return tuple(s)
            A, B, C, D = (ins[sl(0, 0)], ins[sl(1, 0)], ins[sl(1, 1)], ins[sl(0, 1)])
            amb = (A == C) & (B == D) & (A != B)
            if not amb.any():
                continue
            # outside corners of ambiguous faces
            fix[sl(0, 0)] |= amb & ~A
            fix[sl(1, 0)] |= amb & ~B
            fix[sl(1, 1)] |= amb & ~C
            fix[sl(0, 1)] |= amb & ~D
        n = int(fix.sum())
        if n == 0:
            break
        vals[fix] = -1e-6
        changed += n
    return changed


def surface_nets(values: np.ndarray, origin: np.ndarray, h: float):
    """Dual contouring lite: one vertex per sign-changing cell, placed at the
    mean of its edge crossings; one quad per sign-changing grid edge, wound
    counter-clockwise seen from outside (values > 0 outside).

    Returns points (V, 3) and quads (Q, 4) int64.
    """
    v = values
    inside = v < 0
    nx, ny, nz = v.shape
    cshape = (nx - 1, ny - 1, nz - 1)
    acc = np.zeros(cshape + (3,))
    cnt = np.zeros(cshape)
    # crossings on edges along each axis, spread to the 4 cells sharing the edge
    for ax in range(3):
        sl0 = [slice(None)] * 3
        sl1 = [slice(None)] * 3
        sl0[ax] = slice(0, -1)
        sl1[ax] = slice(1, None)
        a, b = v[tuple(sl0)], v[tuple(sl1)]
        cross = (a < 0) != (b < 0)
        t = np.where(cross, a / np.where(cross, a - b, 1.0), 0.0)
        # edge position within a cell: along ax at t, the other two at 0 or 1
        others = [o for o in range(3) if o != ax]
        for da in (0, 1):
            for db in (0, 1):
                # edge e (indices along the edge grid) belongs to cell e - (da, db) on the others
                src = [slice(None)] * 3
                dst = [slice(None)] * 3
                for o, dd in zip(others, (da, db)):
                    size = cshape[o]
                    src[o] = slice(dd, dd + size)
                    dst[o] = slice(0, size)
                c = cross[tuple(src)]
                local = np.zeros(c.shape + (3,))
                local[..., ax] = t[tuple(src)]
                local[..., others[0]] = da
                local[..., others[1]] = db
                acc[tuple(dst)] += local * c[..., None]
                cnt[tuple(dst)] += c
    active = cnt > 0
    ids = -np.ones(cshape, dtype=np.int64)
    ids[active] = np.arange(int(active.sum()))
    ci = np.argwhere(active)
    pts = origin + h * (ci + acc[active] / cnt[active][:, None])
    quads = []
    for ax in range(3):
        b_ax, c_ax = (ax + 1) % 3, (ax + 2) % 3
        sl0 = [slice(None)] * 3
        sl1 = [slice(None)] * 3
        sl0[ax] = slice(0, -1)
        sl1[ax] = slice(1, None)
        a_in = inside[tuple(sl0)]
        b_in = inside[tuple(sl1)]
        cross = a_in != b_in
        # interior edges only (need cells on both sides in b and c)
        e = np.argwhere(cross)
        e = e[(e[:, b_ax] >= 1) & (e[:, b_ax] < v.shape[b_ax] - 1)
              & (e[:, c_ax] >= 1) & (e[:, c_ax] < v.shape[c_ax] - 1)]
        if not len(e):
            continue
        out_dir = a_in[tuple(e.T)]  # inside -> outside along +ax: normal +ax

        def cell(db, dc, e=e, b_ax=b_ax, c_ax=c_ax):
            c = e.copy()
            c[:, b_ax] += db
            c[:, c_ax] += dc
            return ids[tuple(c.T)]
        q = np.stack([cell(-1, -1), cell(0, -1), cell(0, 0), cell(-1, 0)], axis=1)
        q[~out_dir] = q[~out_dir][:, ::-1]
        quads.append(q)
    quads = np.concatenate(quads, axis=0)
    return pts, quads


# --------------------------------------------------------------------------
# mesh helpers

def vertex_adjacency(n: int, polys: np.ndarray):
    """Row-normalised (n, n) sparse adjacency of a polygon mesh (fixed arity)."""
    a = polys.ravel()
    b = np.roll(polys, -1, axis=1).ravel()
    rows = np.concatenate([a, b])
    cols = np.concatenate([b, a])
    m = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()
    m.data[:] = 1.0
    deg = np.asarray(m.sum(axis=1)).ravel()
    return sp.diags(1.0 / np.maximum(deg, 1)) @ m


def relax_on_surface(solid: Solid, points: np.ndarray, polys: np.ndarray, level: float = 0.0,
                     iters: int = 4, amount: float = 0.5, fixed: np.ndarray | None = None,
                     adjacency=None) -> np.ndarray:
    """Umbrella smoothing followed by re-projection onto ``f = level``, which
    evens out the vertex spacing without shrinking the shape."""
    adj = vertex_adjacency(len(points), polys) if adjacency is None else adjacency
    p = np.array(points, dtype=np.float64)
    for _ in range(iters):
        target = adj @ p
        new = p + amount * (target - p)
        if fixed is not None:
            new[fixed] = p[fixed]
        p = solid.project(new, level, iters=3)
        if fixed is not None:
            p[fixed] = new[fixed]
    return p


def best_diagonal(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Rotate each quad so that its fan diagonal (v0-v2) is the shorter one."""
    d02 = np.linalg.norm(points[quads[:, 0]] - points[quads[:, 2]], axis=1)
    d13 = np.linalg.norm(points[quads[:, 1]] - points[quads[:, 3]], axis=1)
    out = quads.copy()
    flip = d13 < d02
    out[flip] = np.roll(quads[flip], -1, axis=1)
    return out
