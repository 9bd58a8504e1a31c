"""Redress: put the items bound on a reference body onto a fitted target body.

Pipeline (internal space, Y up, metres):

1. segment the reference body by skin weights (:mod:`regions`) and give each
   item vertex the region of its nearest body triangle; item parts that join
   the two legs directly (skirts, dresses) are bound to the torso instead, so
   no vertex is pulled by both legs and the skirt cannot tear between them;
2. bind every item vertex to its ``k`` nearest reference triangles of its
   region (:func:`binding.bind`, one sparse matrix for all items);
3. evaluate the binding on the fitted body (reference topology deformed onto
   the target); small stiff parts (shoes, hat, glasses, watch) instead follow
   a best-fit similarity transform of their bound body patch;
4. push item vertices that went inside the target body (but were outside the
   reference body) back out to their reference clearance (:func:`push_out`),
   lift outer layers over inner ones (:func:`keep_layers`), and spread these
   per-vertex corrections smoothly over the item mesh
   (:func:`spread_corrections`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .binding import local_signed_distance
from .body_stretch import skin_range, stretch_range, vertex_stretch
from ..geometry.closest import SurfaceQuery, VertexNormals
from ..geometry.mesh import adjacency, edges, similarity_fit  # noqa: F401
from ..model import Character, Mesh
from ..progress import debug, info
from .corrections import (LOOSE_FULL, LOOSE_ITERATIONS, LOOSE_START, SPREAD_CLEARANCE_DRIFT, SPREAD_LENGTH,  # noqa: F401
                          SPREAD_RINGS, LooseSmoother, looseness, off_skin, push_out, spread_corrections)
from .plan import FAR_FROM_BODY, DressPlan, item_labels, plan  # noqa: F401
from .layers import LAYER_MIN_GAP, LAYER_RADIUS, keep_layers, layer_gaps, layer_order, layer_pairs  # noqa: F401

# --------------------------------------------------------------------------
# penetration

UNTANGLE_CLEARANCE_DRIFT = 0.001  # m: the untangle may worsen an item's median clearance error by at most this



RIGID_RELEASE = 0.05  # rigid groups with more of their vertices newly > 1 mm inside the target move freely
RIGID_RELEASE_DEPTH = 0.01  # m: ... and those with a vertex newly deeper than this inside


def release_misfits(plan_: "DressPlan", body_points: np.ndarray, query: SurfaceQuery,
                    fraction: float = RIGID_RELEASE, depth: float = 0.001,
                    max_depth: float = RIGID_RELEASE_DEPTH):
    """The plan without the rigid groups that do not fit this body.

    A rigid part follows its body patch's similarity; on a body that grew
    unevenly under it (short hair on a head whose sides and nape grew more
    than its top: 8.9 % of the hair 1-17 mm inside on the muscular-heavy
    body), keeping it rigid means pushing those vertices out one by one,
    which bends it anyway (16 mm off its similarity). Groups with more than
    ``fraction`` of their vertices newly more than ``depth`` (m) inside the
    body (query, on body_points (N, 3)) after the similarity placement
    are released: they deform with the binding like any free part (hair
    then lies on the new scalp). So are groups with any vertex newly more
    than ``max_depth`` inside: pushing it out would bend the part by that
    much (shoe collars around the muscular-heavy body's thicker ankles:
    2.9 % of the shoe, 15-16 mm deep, bent 16.6 mm with 6 edges beyond the
    shoe's own scale; released, the shoes follow the feet with no edge
    beyond the body's stretch). Returns (plan, names of the items whose
    groups were released)."""
    if not plan_.rigid_groups:
        return plan_, []
    parts = plan_.rigid_parts
    s, rot, t = parts.transforms(body_points)
    pts = np.array(plan_.ref_points, dtype=np.float64, copy=True)
    parts.place(s, rot, t, pts)
    rows = np.concatenate(parts.groups)
    depth_new = np.zeros(len(pts))
    depth_new[rows] = -query.signed_distance(pts[rows])
    new_in = (plan_.ref_clearance > 0) & (depth_new > depth)
    fits = [np.mean(new_in[gv]) <= fraction and not np.any(new_in[gv] & (depth_new[gv] > max_depth))
            for gv in parts.groups]
    if all(fits):
        return plan_, []

    def item_name(gv):
        return plan_.items[int(np.searchsorted(plan_.offsets, gv[0], side="right") - 1)].name

    still = {item_name(gv) for gv, ok in zip(parts.groups, fits) if ok}
    names = sorted({item_name(gv) for gv, ok in zip(parts.groups, fits) if not ok})
    keep = [group for group, ok in zip(plan_.rigid_groups, fits) if ok]
    return replace(plan_, rigid_groups=keep, rigid_items=[n for n in plan_.rigid_items if n in still]), names


# --------------------------------------------------------------------------
# body fit

def fitted_body_points(ref: Character, target: Character) -> np.ndarray:
    """The reference body topology deformed onto the target (N_ref, 3), by
    :func:`wearfit_usd.body_fit.fit_character`."""
    from ..fit.body_fit import fit_character
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


def untangle_items(plan_: DressPlan, body_points: np.ndarray, pts: np.ndarray, query: SurfaceQuery,
                   target: np.ndarray, rigid_maps: list, bisect_steps: int = 5, relax: bool = True,
                   footprints: dict | None = None, **kw):
    """Run :func:`untangle.untangle` on redressed items (points (M, 3)):
    vertex gradients from the binding (rigid parts: their similarity
    ``s * rot`` from ``rigid_maps`` [(vertex indices, (3, 3))]), constraints
    = :func:`push_out` to ``target`` (M,) clearance (m) and
    :func:`keep_layers`, both restricted to the re-solved vertices. With
    ``relax``, edges still outside the body's stretch range
    (:func:`stretch_limits`) are then brought back into it
    (:func:`untangle.relax_edges`, same constraints). footprints: the
    closest body points of ``pts`` (:meth:`SurfaceQuery.closest` keys
    distance, point, normal) if already known.
    Returns (points (M, 3), touched (M,) bool, stats dict)."""
    from . import untangle as U
    b = plan_.binding
    tg = np.tile(np.eye(3), (len(b.faces), 1, 1))
    tg[b.used] = U.triangle_gradients(plan_.ref_body, body_points, b.faces[b.used])
    grad = U.vertex_gradients(tg, b.triangles, b.weights)
    for gv, lin in rigid_maps:
        grad[gv] = lin
    faces = plan_.item_faces
    if faces is None:
        faces = np.concatenate([m.faces + a for m, a in zip(plan_.items, plan_.offsets[:-1])]).astype(np.int64)
    item_edges = plan_.item_edges if plan_.item_edges is not None else edges(faces)
    tgt = np.nan_to_num(np.asarray(target, dtype=np.float64), nan=-1.0)
    known, footprints_in = footprints is not None, footprints
    if plan_.layers and not known:
        res = query.closest(pts)
        footprints = {k: res[k] for k in ("distance", "point", "normal")}
    elif known:
        footprints = {k: v.copy() for k, v in footprints.items()}  # constrain updates them

    def constrain(p, mask, before):
        # push_out and keep_layers with one closest-point query of the masked
        # vertices. A vertex the solve took inside goes back along its own
        # path to where it re-enters its clearance (bisection between its
        # valid position before the solve and the new one), not to the
        # closest skin point, which can lie on the far side of a thin gap
        # (armpit, crotch) and fold the patch.
        sel = np.flatnonzero(mask)
        res = query.closest(p[sel], ring=False)
        solved = p
        p = p.copy()
        moved = np.zeros(len(p), dtype=bool)
        inside = (res["distance"] < 0) & (tgt[sel] > 0)
        pushed = sel[inside]
        if len(pushed):
            lo = np.zeros(len(pushed))  # fraction of the step known to be fine
            hi = np.ones(len(pushed))
            a, b = before[pushed], p[pushed]
            for _ in range(bisect_steps):
                mid = 0.5 * (lo + hi)
                d = query.closest(a + mid[:, None] * (b - a), ring=False)["distance"]
                ok = d >= np.minimum(tgt[pushed], 0.0005)
                lo = np.where(ok, mid, lo)
                hi = np.where(ok, hi, mid)
            p[pushed] = a + lo[:, None] * (b - a)
            # still inside (the start was inside too): closest skin point
            r2 = query.closest(p[pushed])
            bad = r2["distance"] < 0
            p[pushed[bad]] = off_skin(r2, bad, tgt[pushed[bad]])
            r2["distance"][bad] = tgt[pushed[bad]]
            for k in ("distance", "point", "normal"):
                res[k][inside] = r2[k]
        moved[pushed] = True
        if plan_.layers:
            for k in footprints:
                footprints[k][sel] = res[k]
            p, moved2 = keep_layers(query, p, plan_.offsets, plan_.layers, mask=mask, footprints=footprints)
            moved |= moved2
        if moved.any():
            # per-vertex pushes fold triangles whose corners got different
            # pushes (slivers, concave creases): move such patches as a whole
            p, lifted = U.lift_folds(plan_.ref_points, solved, p, faces, grad, moved)
            moved |= lifted
        return p, moved

    detect = U.BadElements(plan_.ref_points, faces, item_edges, grad)
    new, touched, stats = U.untangle(plan_.ref_points, pts, faces, item_edges, plan_.neighbours, grad,
                                     constrain, detect=detect, **kw)
    if relax:
        # the edges the untangle left outside the body's own stretch range
        # (its gradient field cannot be met across a seam between two body
        # parts, and its constraints move single vertices again)
        # (only edges outside the skin's own range can be outside the full
        # range, which contains it: the full range is found for those and
        # for the relaxed region only)
        fixed = plan_.rigid_mask()
        vr = vertex_stretch(b.triangles, plan_.ref_body, body_points, b.faces)
        cand = np.flatnonzero(U.outside_range(plan_.ref_points, new, item_edges,
                                              *skin_range(item_edges, vr), fixed))
        if len(cand):
            new, relaxed, st = U.relax_edges(
                plan_.ref_points, new, item_edges,
                lambda idx: stretch_limits(plan_, body_points, item_edges[idx], vr),
                plan_.neighbours, fixed, constrain, faces, lambda p: detect(p)[0], candidates=cand)
            touched |= relaxed
            stats.update(st)
    # the untangle must not trade the fit for shape: an item whose median
    # clearance error (|clearance - reference clearance| over all its
    # vertices, the dressing metric) grows by more than
    # UNTANGLE_CLEARANCE_DRIFT keeps its redress (a thin closed tube such as
    # a necklace, freed as a whole, can otherwise slide around the neck)
    # (one query over the touched items before, one over the touched
    # vertices after: the others kept their clearance)
    kept = []
    spans = [(item, a, b) for item, a, b in zip(plan_.items, plan_.offsets[:-1], plan_.offsets[1:])
             if touched[a:b].any()]
    rows = np.concatenate([np.arange(a, b) for _, a, b in spans]) if spans else np.zeros(0, dtype=np.int64)
    d_before = np.zeros(len(pts))
    if known:
        d_before[rows] = footprints_in["distance"][rows]
    else:
        d_before[rows] = query.closest(pts[rows])["distance"]
    d_after = d_before.copy()
    tv = np.flatnonzero(touched)
    d_after[tv] = query.closest(new[tv])["distance"]
    for item, a, b in spans:
        ref_c = plan_.ref_clearance[a:b]
        err_before = np.median(np.abs(d_before[a:b] - ref_c))
        err_after = np.median(np.abs(d_after[a:b] - ref_c))
        if err_after > err_before + UNTANGLE_CLEARANCE_DRIFT:
            new[a:b] = pts[a:b]
            touched[a:b] = False
            kept.append(item.name)
    stats["reverted_items"] = kept
    return new, touched, stats


def stretch_limits(plan_: DressPlan, body_points: np.ndarray, item_edges: np.ndarray,
                   vertex_range: tuple | None = None):
    """(lo (E,), hi (E,)): the body's own stretch range (edge-length ratios,
    :func:`body_stretch.stretch_range`) of item edges (E, 2) (stacked
    indices) from the plan's reference body to ``body_points`` (N, 3), the
    range :func:`metrics.shape_change` judges them by; vertex_range:
    :func:`body_stretch.vertex_stretch` of the binding if already known."""
    b = plan_.binding
    if plan_.ref_foot is None:
        res = SurfaceQuery(b.faces, plan_.ref_body).closest(plan_.ref_points)
        foot = (res["triangle"], res["bary"])
    else:
        foot = plan_.ref_foot
    return stretch_range(plan_.ref_points, item_edges, b.triangles, plan_.ref_body, body_points, b.faces,
                         foot[0], foot[1], plan_.ref_clearance, vertex_range)


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
