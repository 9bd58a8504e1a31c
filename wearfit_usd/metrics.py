"""Fit-quality measures of redressed items (plain numpy; used by `wearfit
dress --report`, `wearfit demo` and the benchmarks).

All distances in metres unless a key says ``_mm``/``_pct``.
"""
from __future__ import annotations

import numpy as np

from .clearance import SurfaceQuery


def _frames(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Orthonormal frame (T, 3, 3) per triangle: rows e1/|e1|, n, e1 x n."""
    e1 = points[faces[:, 1]] - points[faces[:, 0]]
    e2 = points[faces[:, 2]] - points[faces[:, 0]]
    n = np.cross(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    e1 = e1 / np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-300)
    return np.stack([e1, n, np.cross(e1, n)], axis=1)


def _unit_normals(p: np.ndarray, faces: np.ndarray) -> np.ndarray:
    n = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def flip_and_stretch(ref_pts: np.ndarray, new_pts: np.ndarray, faces: np.ndarray, tri0: np.ndarray,
                     ref_body: np.ndarray, fit_body: np.ndarray, body_faces: np.ndarray):
    """Flipped item triangles and over-stretched item edges, in percent.

    ref_pts/new_pts (M, 3) item before/after, faces (F, 3) item triangles,
    tri0 (M,) the body triangle each item vertex is bound to first,
    ref_body/fit_body (N, 3) the body (reference topology) before/after.
    A triangle is flipped when its normal, turned by its body triangle's local
    rotation, opposes the new normal; an edge is over-stretched when its length
    ratio leaves [0.8, 1.25] x the range of its body triangle's edge ratios.
    """
    from .redress import edges
    fr, ft = _frames(ref_body, body_faces), _frames(fit_body, body_faces)
    t = tri0[faces[:, 0]]
    rot = np.einsum("tji,tjk->tik", fr[t], ft[t])  # row-vector rotation ref -> target
    nr, nt = _unit_normals(ref_pts, faces), _unit_normals(new_pts, faces)
    ok = np.linalg.norm(np.cross(ref_pts[faces[:, 1]] - ref_pts[faces[:, 0]],
                                 ref_pts[faces[:, 2]] - ref_pts[faces[:, 0]]), axis=1) > 1e-12
    flipped = (np.einsum("ti,tij,tj->t", nr, rot, nt) < 0) & ok
    e = edges(faces)
    lr = np.linalg.norm(ref_pts[e[:, 0]] - ref_pts[e[:, 1]], axis=1)
    lt = np.linalg.norm(new_pts[e[:, 0]] - new_pts[e[:, 1]], axis=1)
    ratio = lt / np.maximum(lr, 1e-12)
    bf = body_faces[tri0[e[:, 0]]]
    br = np.stack([np.linalg.norm(fit_body[bf[:, i]] - fit_body[bf[:, (i + 1) % 3]], axis=1)
                   / np.maximum(np.linalg.norm(ref_body[bf[:, i]] - ref_body[bf[:, (i + 1) % 3]], axis=1),
                                1e-12) for i in range(3)], axis=1)
    out = (ratio < 0.8 * br.min(axis=1)) | (ratio > 1.25 * br.max(axis=1))
    return 100.0 * float(flipped[ok].mean()) if ok.any() else 0.0, 100.0 * float(out.mean())


def clearance_change(ref_clearance: np.ndarray, new_clearance: np.ndarray, inside: float = 0.001) -> dict:
    """New penetrations (outside the reference body, > ``inside`` m inside the
    target) and the change of clearance, for one item."""
    ch = np.abs(new_clearance - ref_clearance)
    return {"new_pen_pct": 100.0 * float(np.mean((ref_clearance > 0) & (new_clearance < -inside))),
            "clear_med_mm": 1000.0 * float(np.median(ch)),
            "clear_p95_mm": 1000.0 * float(np.percentile(ch, 95))}


def dress_report(reference, target, result) -> list[dict]:
    """Per-item quality of a :class:`redress.DressResult` (reference and target
    are :class:`Character`): new penetration %, clearance change median/p95 mm,
    flipped triangles %, over-stretched edges %."""
    qr = SurfaceQuery(reference.body.faces, reference.body.points)
    qt = SurfaceQuery(target.body.faces, target.body.points)
    pl = result.plan
    rows = []
    for item, new, sl in zip(pl.items, result.items, pl.item_slices()):
        dr = qr.signed_distance(item.points)
        dt = qt.signed_distance(new.points)
        flip, stretch = flip_and_stretch(item.points, new.points, item.faces, pl.binding.triangles[sl, 0],
                                         reference.body.points, result.body_points, reference.body.faces)
        rows.append({"item": item.name, "verts": item.n_points, **clearance_change(dr, dt),
                     "flipped_pct": flip, "overstretch_pct": stretch,
                     "rigid": item.name in pl.rigid_items})
    return rows
