"""Dressing a target: a plan evaluated on the fitted body, with the
penetration, layer and untangle passes (:func:`apply`), and the whole
dressing of one target from a reference (:func:`dress`).

Pipeline (internal space, Y up, metres):

1. fit the reference body onto the target (:func:`fitted_body_points`) and
   plan the items on the reference (:func:`plan.plan`);
2. evaluate the binding on the fitted body (reference topology deformed onto
   the target); small stiff parts (shoes, hat, glasses, watch) instead follow
   a best-fit similarity transform of their bound body patch, loose parts are
   smoothed;
3. push item vertices that went inside the target body (but were outside the
   reference body) back out to their reference clearance
   (:func:`corrections.push_out`), lift outer layers over inner ones
   (:func:`layers.keep_layers`), and spread these per-vertex corrections
   smoothly over the item mesh (:func:`corrections.spread_corrections`);
4. untangle folded or over-stretched patches (:func:`repair.untangle_items`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .binding import local_signed_distance
from .corrections import SPREAD_CLEARANCE_DRIFT, push_out, spread_corrections
from .layers import keep_layers
from .plan import DressPlan, plan
from .repair import release_misfits, untangle_items
from ..fit.body_fit import fit_character
from ..geometry.closest import SurfaceQuery, VertexNormals
from ..model import Character, Mesh
from ..progress import debug, info

def fitted_body_points(ref: Character, target: Character) -> np.ndarray:
    """The reference body topology deformed onto the target (N_ref, 3), by
    :func:`fit.body_fit.fit_character`."""
    return np.asarray(fit_character(ref, target).points, dtype=np.float64)



@dataclass
class DressResult:
    items: list[Mesh]          # redressed items (internal space), names/topology as the reference
    points: np.ndarray         # (M, 3) all item points stacked
    free_points: np.ndarray    # (M, 3) binding result before rigid parts and push-out
    moved: np.ndarray          # (M,) bool: changed by the penetration pass
    plan: DressPlan
    body_points: np.ndarray    # the fitted body (reference topology)
    timings: dict


def apply(plan_: DressPlan, body_points: np.ndarray, body_faces: np.ndarray,
          penetration: bool = True, query: SurfaceQuery | None = None, margin: float = 0.003,
          near_other: float = 0.03, push_inherited: bool = False, inherited_clearance: float = 0.001,
          untangle: bool = True, spread: bool = True):
    """Evaluate a plan on fitted body points (reference topology).

    Vertices that end inside the body but were outside the reference body
    are pushed out to their reference clearance. Those that were inside the
    reference body already keep their (negative) reference clearance, as
    every other vertex does: dressing the reference onto its own shape gives
    the reference back. With ``push_inherited`` the ones deeper than
    ``inherited_clearance`` are pushed out to that clearance instead (a flaw
    of the asset, e.g. a tight suit fitted by MakeHuman, which hides the skin
    under clothes with ``delete_verts``: the skin would show through); this
    repair flattens folds that dip into the body and so shortens their
    edges. Vertices of the plan's rigid groups always keep such authored
    insets (they move as a whole; a shoe's insole stays inside the sole also
    where :func:`release_misfits` freed the shoe on this body).

    spread: the penetration and layer passes move single vertices; spread
    their corrections smoothly over the item mesh (:func:`spread_corrections`,
    every vertex at least as far as its own correction; rigid parts
    excluded) instead of only smoothing their 1-ring.

    untangle: after the penetration and layer passes, re-solve the
    neighbourhoods of folded item triangles and badly stretched edges so they
    deform like the body under them, under the same constraints
    (:func:`untangle_items`; only with ``penetration``).

    Returns (points (M, 3), free points (M, 3), moved (M,) bool, timings).
    """
    t0 = time.perf_counter()
    free = plan_.binding.evaluate(body_points)
    pts = free.copy()
    rigid_maps = []
    if plan_.rigid_groups:
        parts = plan_.rigid_parts
        s, rot, t = parts.transforms(body_points)
        parts.place(s, rot, t, pts)
        rigid_maps = [(gv, s[i] * rot[i]) for i, gv in enumerate(parts.groups)]
    if plan_.smoother is not None:
        pts = plan_.smoother(pts, plan_.ref_points)
    t1 = time.perf_counter()
    moved = np.zeros(len(pts), dtype=bool)
    if penetration:
        if query is None:
            query = SurfaceQuery(body_faces, body_points)
        # cheap local test against the vertex's own bound triangles: only
        # vertices close to (or inside) them, or close to another body
        # region (a posed limb pressing into the torso...), get the exact
        # signed-distance query
        d_loc, _ = local_signed_distance(plan_.binding, body_points, pts)
        cand = d_loc < margin
        dn, vn = cKDTree(body_points).query(pts, k=1)
        cand |= (plan_.body_labels[vn] != plan_.labels) & (dn < near_other)
        # a bulge of the same region (a heavier belly or thigh under a loose
        # skirt) is far from the vertex's own triangles: estimate the
        # clearance through the nearest body vertex and its normal too
        normals = VertexNormals(body_faces, len(body_points))(body_points)
        est = np.einsum("ij,ij->i", pts - body_points[vn], normals[vn])
        cand |= est < margin
        # inherited: only deeper than inherited_clearance (skin showing through);
        # shallower ones lie on the skin (eyebrows) and are left alone. Rigid
        # parts keep their authored insets (a shoe's insole 0.5-5 mm inside
        # the foot sole, hair-card roots under the scalp): they move as a
        # whole, and pushing single vertices of them out to the surface is
        # what bent them (every over-stretched shoe and short-hair edge on
        # the reference-shaped CMU-rig body came from it); they are still
        # pushed out where they newly penetrate
        rig = plan_.rigid_mask()
        inherited = push_inherited & (plan_.ref_clearance < -inherited_clearance)
        # (the plan's rigid parts, also when released on this body)
        inherited &= ~(plan_.insets_kept if plan_.insets_kept is not None else rig)
        target = np.where(plan_.ref_clearance > 0, plan_.ref_clearance,
                          np.where(inherited, inherited_clearance, np.nan))
        debug(f"penetration pass: {int(cand.sum())} of {len(cand)} vertices tested")
        # with ``spread`` the per-vertex corrections are made alone and then
        # spread over the item mesh (spread_corrections), which replaces
        # push_out's light smoothing of the 1-ring
        before = pts
        ring_nb = plan_.neighbours
        if spread:  # rigid parts (not spread) keep the 1-ring smoothing
            ring_nb = (sp.diags(rig.astype(np.float64)) @ plan_.neighbours @ sp.diags(rig.astype(np.float64))
                       + sp.diags((~rig).astype(np.float64))).tocsr()
        pts, moved = push_out(query, pts, target, mask=cand, neighbours=ring_nb)
        if plan_.smoother is not None and np.any(moved & (plan_.looseness > 0)):
            # loose parts: spread the push over the neighbourhood (a smooth
            # bulge, not a spike), then push out what went back inside
            pts = plan_.smoother(pts, plan_.ref_points)
            again = cand | moved
            pts, moved2 = push_out(query, pts, target, mask=again, neighbours=ring_nb)
            moved |= moved2
        footprints = None
        if plan_.layers:
            # layers keep their order: an outer item stays over the item under it
            res = query.closest(pts)
            footprints = {k: res[k] for k in ("distance", "point", "normal")}
            foot_at = pts.copy()  # where each footprint was taken

            def refresh_footprints(pts):
                # re-query the vertices moved since their footprint was taken
                sv = np.flatnonzero((pts != foot_at).any(axis=1))
                res = query.closest(pts[sv])
                for k in footprints:
                    footprints[k][sv] = res[k]
                foot_at[sv] = pts[sv]
            pts, moved3 = keep_layers(query, pts, plan_.offsets, plan_.layers, footprints=footprints)
            moved |= moved3
        if spread:
            # single-vertex corrections stretch every edge at them: spread
            # them smoothly over the item, each vertex still at least as far
            # as its own; then check the spread vertices once more
            req = moved | (np.abs(pts - before).max(axis=1) > 1e-6)
            single = pts
            pts, spread_v = spread_corrections(plan_.ref_points, before, single, req, plan_.neighbours, fixed=rig)
            # an item the spread would move as a whole (a thin necklace lifted
            # over a shirt) keeps the single-vertex corrections: the spread
            # may change its median clearance by at most SPREAD_CLEARANCE_DRIFT
            # (its extra displacement bounds the clearance change)
            extra = np.linalg.norm(pts - single, axis=1)
            for a, b in zip(plan_.offsets[:-1], plan_.offsets[1:]):
                if spread_v[a:b].any() and np.median(extra[a:b]) > SPREAD_CLEARANCE_DRIFT:
                    pts[a:b] = single[a:b]
                    spread_v[a:b] = False
            if spread_v.any():
                # only vertices the spread moved by more than their estimated
                # clearance (less the margin) can have gone inside
                shift = np.linalg.norm(pts - before, axis=1)
                check = spread_v & (np.minimum(d_loc, est) < shift + margin)
                pts, moved4 = push_out(query, pts, target, mask=check)
                moved |= spread_v | moved4
                if plan_.layers:
                    refresh_footprints(pts)
                    pts, moved5 = keep_layers(query, pts, plan_.offsets, plan_.layers, mask=spread_v,
                                              footprints=footprints)
                    moved |= moved5
        if footprints is not None:
            refresh_footprints(pts)  # for the untangle
    t2 = time.perf_counter()
    timings = {"evaluate_s": t1 - t0, "penetration_s": t2 - t1}
    if penetration and untangle:
        pts, touched, stats = untangle_items(plan_, body_points, pts, query, target, rigid_maps,
                                             footprints=footprints)
        moved |= touched
        timings["untangle_s"] = time.perf_counter() - t2
        debug(f"untangle: {stats}")
    return pts, free, moved, timings


def dress(ref: Character, target: Character, k: int = 5, use_regions: bool = True,
          rigid="auto", penetration: bool = True, body_points: np.ndarray | None = None,
          strict_far: bool = False, bind_labels: np.ndarray | None = None,
          skirt_items: list[str] | None = None, ref_clearance: np.ndarray | None = None,
          push_inherited: bool = False, untangle: bool = True,
          prepared: DressPlan | None = None) -> DressResult:
    """Put every item of ``ref`` on ``target``'s body (internal space).
    ``bind_labels``/``skirt_items``/``ref_clearance``: see :func:`plan`;
    ``push_inherited``, ``untangle``: see :func:`apply`. ``prepared``: a plan
    of ``ref`` made earlier (e.g. :meth:`DressPlan.rebound`), used instead of
    a new one (the plan options are then ignored)."""
    tb = time.perf_counter()
    if body_points is None:
        body_points = fitted_body_points(ref, target)
    t_fit = time.perf_counter() - tb
    if prepared is not None:
        p = prepared
    else:
        p = plan(ref, k=k, use_regions=use_regions, rigid=rigid, strict_far=strict_far,
                 bind_labels=bind_labels, skirt_items=skirt_items, ref_clearance=ref_clearance)
    query = None
    if penetration:  # the plan's reference-body query has this topology
        query = (p.body_query.moved_to(body_points) if p.body_query is not None
                 else SurfaceQuery(ref.body.faces, body_points))
    if penetration and p.rigid_groups:
        p, released = release_misfits(p, body_points, query)
        if released:
            info(f"{target.source}: rigid parts that do not fit this body move freely: {', '.join(released)}")
    pts, free, moved, tm = apply(p, body_points, ref.body.faces, penetration=penetration, query=query,
                                 push_inherited=push_inherited, untangle=untangle)
    timings = {"body_fit_s": t_fit, **p.timings, **tm}
    keep_weights = (target.skeleton is not None and ref.skeleton is not None
                    and target.skeleton.joint_names == ref.skeleton.joint_names)
    out = []
    for item, sl in zip(p.items, p.item_slices()):
        m = item.copy_with_points(pts[sl])
        if not keep_weights:  # influences index the reference skeleton's joints
            m.joint_indices = None
            m.joint_weights = None
        out.append(m)
    debug(f"dress timings: {timings}")
    return DressResult(items=out, points=pts, free_points=free, moved=moved, plan=p,
                       body_points=body_points, timings=timings)
