"""Fit-quality measures of redressed items (plain numpy; used by `wearfit
dress --report`, `wearfit demo` and the benchmarks).

All distances in metres unless a key says ``_mm``/``_pct``.
"""
from __future__ import annotations

import numpy as np

from ..geometry.closest import SurfaceQuery
from ..geometry.mesh import edges, nondegenerate, similarity_fit
from . import untangle as U
from .body_stretch import stretch_range


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
    """Flipped item triangles and over-stretched item edges, in percent: the
    strict single-triangle definition (the secondary figures of
    :func:`shape_change`).

    ref_pts/new_pts (M, 3) item before/after, faces (F, 3) item triangles,
    tri0 (M,) the body triangle each item vertex is bound to first,
    ref_body/fit_body (N, 3) the body (reference topology) before/after.
    A triangle is flipped when its normal, turned by its body triangle's local
    rotation, opposes the new normal; an edge is over-stretched when its length
    ratio leaves [0.8, 1.25] x the range of its body triangle's edge ratios.
    Zero-area reference triangles (:func:`geometry.mesh.nondegenerate`) have
    no normal and are left out of the flipped percentage.
    """
    fr, ft = _frames(ref_body, body_faces), _frames(fit_body, body_faces)
    t = tri0[faces[:, 0]]
    rot = np.einsum("tji,tjk->tik", fr[t], ft[t])  # row-vector rotation ref -> target
    nr, nt = _unit_normals(ref_pts, faces), _unit_normals(new_pts, faces)
    ok = nondegenerate(ref_pts, faces)
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


DEGENERATE_MIN_ANGLE = 1.0  # degrees: reference item triangles below this have no well-defined normal


def min_angle_deg(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) smallest interior angle (degrees) of each triangle (F, 3) of points (M, 3)."""
    p = points[faces]
    ang = []
    for c in range(3):
        u, v = p[:, (c + 1) % 3] - p[:, c], p[:, (c + 2) % 3] - p[:, c]
        cs = np.einsum("fi,fi->f", u, v) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-300)
        ang.append(np.degrees(np.arccos(np.clip(cs, -1.0, 1.0))))
    return np.min(ang, axis=0)


def shape_change(ref_pts: np.ndarray, new_pts: np.ndarray, faces: np.ndarray, triangles: np.ndarray,
                 weights: np.ndarray, ref_body: np.ndarray, fit_body: np.ndarray, body_faces: np.ndarray,
                 ref_clearance: np.ndarray | None = None, tri0: np.ndarray | None = None,
                 rigid_groups: list | None = None) -> dict:
    """Flipped item triangles and edges stretched beyond the body's local
    stretch, for one item, against the deformation of the body under it.

    ref_pts/new_pts (M, 3) item before/after, faces (F, 3) its triangles,
    triangles/weights (M, K) its binding (bound body triangles, blend
    weights), ref_body/fit_body (N, 3) the body (reference topology) on the
    reference and the target, body_faces (T, 3); ref_clearance (M,) signed
    clearance on the reference (m; default: queried); tri0 (M,) the single
    body triangle of each vertex for the strict secondary figures (default
    ``triangles[:, 0]``).

    Flipped (``flipped_pct``): the reference normal of an item triangle,
    carried by the expected local deformation, opposes its new normal. The
    expected deformation is the body's deformation gradient (frames
    ``[e1, e2, unit normal]``) blended with the binding weights over each
    corner's K triangles and averaged over the 3 corners: the deformation
    the binding itself applies, and the one the untangle pass fits.
    Reference triangles whose smallest angle is below
    ``DEGENERATE_MIN_ANGLE`` (1 degree) are left out and counted
    (``degenerate``): their smallest altitude is below 1.75 % of their
    longest edge (0.3 mm on a 20 mm hair-card sliver), so an out-of-plane
    offset of that vertex by a fraction of a millimetre - well inside the
    millimetre-level clearance the dressing keeps - turns the normal by
    tens of degrees: its direction is not defined at that scale. The
    percentage is over the non-degenerate triangles.

    Over-stretched (``overstretch_pct``): an item edge's length ratio
    (new / reference) leaves [0.8, 1.25] x the body's own local stretch,
    the range of stretch, over all directions, of every body triangle
    either endpoint is bound to (2K triangles: from the smallest to the
    largest principal stretch, :func:`principal_stretches`; a triangle's
    three edges sample only three directions of it, and an item edge along
    the skin's direction of greatest stretch - across a raised arm's
    armpit - legitimately stretches more than any of them), widened by the offset factor
    of the item's clearance: an offset surface at clearance c over skin of
    normal curvature k along the edge is ``1 + c k`` times as long as the
    skin, so where the target's skin bends more or less the item legitimately
    changes by ``(1 + c k_fit) / (1 + c k_ref)`` on top of the skin's
    stretch (``(R' + c) / (R + c)`` for a cylinder of radius R -> R'); the
    range spans both the skin's ratios and those ratios times the factor.

    Rigid parts (``rigid_groups``: list of vertex index arrays (P,) of this
    item, each moved as a whole by one similarity transform, see
    :func:`plan.plan`): an edge with both endpoints in one group is not
    judged by the body's stretch but by the rigid part's own criterion: its
    length ratio must lie within [0.8, 1.25] x the uniform scale ``s`` of the
    best-fit similarity (Umeyama) of the group's reference points onto its
    new points. The similarity changes every edge by exactly ``s``, while
    the body under a shoe or a hat stretches unevenly (a foot grows longer
    than it grows wide): a rigid part that keeps its shape can leave the
    body's range although nothing in it stretched, and a rigid part bent by
    per-vertex corrections can stay inside the body's range although it no
    longer keeps its shape. These edges are left out of ``overstretch_pct``
    and counted separately: ``rigid_edges``, ``overstretch_rigid_pct`` (% of
    them beyond the rigid criterion) and ``rigid_residual_mm`` (largest
    distance of a group vertex from the best-fit similarity image of its
    reference position: how far the part was bent, 0 for a pure
    similarity). ``overstretch_pct`` is over the other edges (0 if none).

    Strict secondary figures (the earlier definition): ``flipped_strict_pct``
    turns the normal by the rotation of one body triangle (``tri0`` of the
    first corner), no triangle excluded; ``overstretch_strict_pct`` uses the
    edge ratios of that one triangle of the edge's first vertex and no
    offset factor.

    Returns a dict: flipped_pct, degenerate (count), flipped_degenerate
    (how many of those would count as flipped), flipped_strict_pct,
    overstretch_pct, overstretch_strict_pct, rigid_edges,
    overstretch_rigid_pct, rigid_residual_mm, and the indices ``flipped``
    (triangles), ``overstretched`` (free edges beyond the body's range) and
    ``overstretched_rigid`` (rigid edges beyond their scale), both rows of
    :func:`geometry.mesh.edges`.
    """
    ref_pts = np.asarray(ref_pts, dtype=np.float64)
    new_pts = np.asarray(new_pts, dtype=np.float64)
    tri0 = triangles[:, 0] if tri0 is None else tri0
    strict_flip, strict_stretch = flip_and_stretch(ref_pts, new_pts, faces, tri0, ref_body, fit_body, body_faces)
    used = np.unique(triangles)
    tg = np.tile(np.eye(3), (len(body_faces), 1, 1))
    tg[used] = U.triangle_gradients(ref_body, fit_body, body_faces[used])
    grad = U.vertex_gradients(tg, triangles, weights)
    n_exp = U.expected_normals(ref_pts, faces, grad)
    area_ok = np.linalg.norm(n_exp, axis=1) > 0
    flipped = U.folded_triangles(n_exp, new_pts, faces) & area_ok
    degenerate = min_angle_deg(ref_pts, faces) < DEGENERATE_MIN_ANGLE
    counted = area_ok & ~degenerate
    qr = SurfaceQuery(body_faces, ref_body)
    res = qr.closest(ref_pts)
    if ref_clearance is None:
        ref_clearance = res["distance"]
    e = edges(faces)
    lo, hi = stretch_range(ref_pts, e, triangles, ref_body, fit_body, body_faces,
                           res["triangle"], res["bary"], ref_clearance)
    le_r = np.linalg.norm(ref_pts[e[:, 1]] - ref_pts[e[:, 0]], axis=1)
    lt = np.linalg.norm(new_pts[e[:, 1]] - new_pts[e[:, 0]], axis=1)
    ratio = lt / np.maximum(le_r, 1e-12)
    over = (ratio < 0.8 * lo) | (ratio > 1.25 * hi)
    rig = rigid_edge_check(ref_pts, new_pts, e, ratio, rigid_groups)
    free = ~rig["rigid"]
    n_free = int(free.sum())
    n_counted = int(counted.sum())
    return {"flipped_pct": 100.0 * float((flipped & counted).sum()) / n_counted if n_counted else 0.0,
            "degenerate": int((degenerate & area_ok).sum()),
            "flipped_degenerate": int((flipped & degenerate).sum()),
            "flipped_strict_pct": strict_flip,
            "overstretch_pct": 100.0 * float((over & free).sum()) / n_free if n_free else 0.0,
            "overstretch_strict_pct": strict_stretch,
            "rigid_edges": int(rig["rigid"].sum()),
            "overstretch_rigid_pct": rig["over_pct"], "rigid_residual_mm": rig["residual_mm"],
            "flipped": np.flatnonzero(flipped & counted), "overstretched": np.flatnonzero(over & free),
            "overstretched_rigid": np.flatnonzero(rig["over"])}


def rigid_edge_check(ref_pts: np.ndarray, new_pts: np.ndarray, e: np.ndarray, ratio: np.ndarray,
                     rigid_groups: list | None) -> dict:
    """The rigid parts' own shape criterion (see :func:`shape_change`).

    ref_pts/new_pts (M, 3), edges e (E, 2) with length ratios (E,),
    rigid_groups: vertex index arrays (P,) (None or empty: no rigid part).
    Returns {"rigid" (E,) bool: both endpoints in one group, "over" (E,)
    bool: ratio outside [0.8, 1.25] x the group's fitted uniform scale,
    "over_pct": % of the rigid edges, "residual_mm": largest distance (mm)
    of a group vertex from the best-fit similarity image of its reference
    position}."""
    group = np.full(len(ref_pts), -1)
    scale = np.ones(len(rigid_groups or []))
    residual = 0.0
    for g, gv in enumerate(rigid_groups or []):
        gv = np.asarray(gv, dtype=np.int64)
        if len(gv) < 3:
            continue
        group[gv] = g
        s, rot, t = similarity_fit(ref_pts[gv], new_pts[gv])
        scale[g] = s
        residual = max(residual, float(np.linalg.norm(s * ref_pts[gv] @ rot + t - new_pts[gv], axis=1).max()))
    ga = group[e[:, 0]] if len(e) else np.zeros(0, dtype=np.int64)
    rigid = (ga >= 0) & (ga == group[e[:, 1]]) if len(e) else np.zeros(0, dtype=bool)
    s_e = scale[np.where(rigid, ga, 0)] if len(scale) else np.ones(len(e))
    over = rigid & ((ratio < 0.8 * s_e) | (ratio > 1.25 * s_e))
    n = int(rigid.sum())
    return {"rigid": rigid, "over": over, "over_pct": 100.0 * float(over.sum()) / n if n else 0.0,
            "residual_mm": 1000.0 * residual}


def clearance_change(ref_clearance: np.ndarray, new_clearance: np.ndarray, inside: float = 0.001) -> dict:
    """New penetrations (outside the reference body, > ``inside`` m inside the
    target) and the change of clearance, for one item."""
    ch = np.abs(new_clearance - ref_clearance)
    return {"new_pen_pct": 100.0 * float(np.mean((ref_clearance > 0) & (new_clearance < -inside))),
            "clear_med_mm": 1000.0 * float(np.median(ch)),
            "clear_p95_mm": 1000.0 * float(np.percentile(ch, 95))}


def item_rigid_groups(plan, sl: slice) -> list:
    """The rigid groups of a :class:`plan.DressPlan` that lie in the item
    of rows ``sl``, as vertex indices of that item."""
    return [np.asarray(gv) - sl.start for gv, _, _ in plan.rigid_groups
            if len(gv) and sl.start <= int(np.min(gv)) and int(np.max(gv)) < sl.stop]


def dress_report(reference, target, result) -> list[dict]:
    """Per-item quality of a :class:`apply.DressResult` (reference and target
    are :class:`Character`): new penetration %, clearance change median/p95 mm,
    flipped triangles % and over-stretched edges % (:func:`shape_change`: main
    and strict figures, degenerate reference triangles left out and counted)."""
    qr = SurfaceQuery(reference.body.faces, reference.body.points)
    qt = SurfaceQuery(target.body.faces, target.body.points)
    pl = result.plan
    rows = []
    for item, new, sl in zip(pl.items, result.items, pl.item_slices()):
        dr = qr.signed_distance(item.points)
        dt = qt.signed_distance(new.points)
        sc = shape_change(item.points, new.points, item.faces, pl.binding.triangles[sl], pl.binding.weights[sl],
                          reference.body.points, result.body_points, reference.body.faces, dr,
                          rigid_groups=item_rigid_groups(pl, sl))
        rows.append({"item": item.name, "verts": item.n_points, **clearance_change(dr, dt),
                     **{k: v for k, v in sc.items() if k not in ("flipped", "overstretched", "overstretched_rigid")},
                     "rigid": item.name in pl.rigid_items})
    return rows
