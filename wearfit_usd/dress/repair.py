"""Repairs of dressed items on a given body (plain numpy; lengths in metres).

- :func:`release_misfits`: rigid groups that do not fit this body are
  released to the binding before the plan is applied;
- :func:`untangle_items`: after the penetration and layer passes, the
  neighbourhoods of folded item triangles and badly stretched edges are
  re-solved so they deform like the body under them (:mod:`untangle`), within
  the body's own stretch range (:func:`stretch_limits`).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..geometry.closest import SurfaceQuery
from . import untangle as U
from .body_stretch import skin_range, stretch_range, vertex_stretch
from .corrections import off_skin
from .layers import keep_layers
from .plan import DressPlan

UNTANGLE_CLEARANCE_DRIFT = 0.001  # m: the untangle may worsen an item's median clearance error by at most this
RIGID_RELEASE = 0.05  # rigid groups with more of their vertices newly > 1 mm inside the target move freely
RIGID_RELEASE_DEPTH = 0.01  # m: ... and those with a vertex newly deeper than this inside


def release_misfits(plan_: DressPlan, body_points: np.ndarray, query: SurfaceQuery,
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
    freed = [group for group, ok in zip(plan_.rigid_groups, fits) if not ok]
    return replace(plan_, rigid_groups=keep, rigid_items=[n for n in plan_.rigid_items if n in still],
                   released_groups=list(plan_.released_groups) + freed), names


def deformation_gradients(plan_: DressPlan, body_points: np.ndarray, rigid_maps: list) -> np.ndarray:
    """The deformation each item vertex should follow: the body's triangle
    gradients from the plan's reference body to ``body_points``, blended with
    the binding weights; rigid parts' vertices take their group's linear map.

    Parameters
    ----------
    plan_ : DressPlan
    body_points : (N, 3) float array
    rigid_maps : list
        [(vertex indices (P,), linear map ``s * rot`` (3, 3))] per rigid group.

    Returns
    -------
    (M, 3, 3) float array
    """
    b = plan_.binding
    tg = np.tile(np.eye(3), (len(b.faces), 1, 1))
    tg[b.used] = U.triangle_gradients(plan_.ref_body, body_points, b.faces[b.used])
    grad = U.vertex_gradients(tg, b.triangles, b.weights)
    for gv, lin in rigid_maps:
        grad[gv] = lin
    return grad


class UntangleConstraints:
    """The constraints of the untangle: ``constrain`` of :func:`untangle.untangle`
    and :func:`untangle.relax_edges`.

    Called as ``constraints(points (M, 3), mask (M,) bool, before (M, 3)) ->
    (points (M, 3), moved (M,) bool)``: to the masked (re-solved) vertices
    only, the push-out to their target clearance and the layer order of the
    plan, with one closest-point query of the masked vertices; then the
    patches these per-vertex moves folded are lifted as a whole
    (:func:`untangle.lift_folds`). A vertex the solve took inside goes back
    along its own path to where it re-enters its clearance
    (:meth:`back_to_clearance`), not to the closest skin point, which can lie
    on the far side of a thin gap (armpit, crotch) and fold the patch.

    Parameters
    ----------
    plan_ : DressPlan
    query : SurfaceQuery
        On the current body.
    target : (M,) float array
        Clearance (m) to push out to; NaN = none.
    faces : (F, 3) int array
        The items' stacked triangles.
    grad : (M, 3, 3) float array
        :func:`deformation_gradients`.
    footprints : dict or None
        Closest body points of the items (:meth:`SurfaceQuery.closest` keys
        distance, point, normal), updated in place for the layer pass; None
        only for a plan without layers.
    bisect_steps : int
        Halvings of the path back to the clearance.
    """

    def __init__(self, plan_: DressPlan, query: SurfaceQuery, target: np.ndarray, faces: np.ndarray,
                 grad: np.ndarray, footprints: dict | None, bisect_steps: int = 5):
        self.plan = plan_
        self.query = query
        self.target = np.nan_to_num(np.asarray(target, dtype=np.float64), nan=-1.0)
        self.faces = faces
        self.grad = grad
        self.footprints = footprints
        self.bisect_steps = bisect_steps

    def __call__(self, points: np.ndarray, mask: np.ndarray, before: np.ndarray):
        sel = np.flatnonzero(mask)
        res = self.query.closest(points[sel], ring=False)
        p = points.copy()
        moved = np.zeros(len(p), dtype=bool)
        inside = (res["distance"] < 0) & (self.target[sel] > 0)
        pushed = sel[inside]
        if len(pushed):
            p[pushed], closest = self.back_to_clearance(before[pushed], p[pushed], self.target[pushed])
            for k in ("distance", "point", "normal"):
                res[k][inside] = closest[k]
        moved[pushed] = True
        if self.plan.layers:
            for k in self.footprints:
                self.footprints[k][sel] = res[k]
            p, lifted = keep_layers(self.query, p, self.plan.offsets, self.plan.layers, mask=mask,
                                    footprints=self.footprints)
            moved |= lifted
        if moved.any():
            # per-vertex pushes fold triangles whose corners got different
            # pushes (slivers, concave creases): move such patches as a whole
            p, lifted = U.lift_folds(self.plan.ref_points, points, p, self.faces, self.grad, moved)
            moved |= lifted
        return p, moved

    def back_to_clearance(self, start: np.ndarray, end: np.ndarray, target: np.ndarray):
        """Vertices that moved from ``start`` to ``end`` into the body: the point of
        that path where they re-enter their clearance (or 0.5 mm if smaller),
        found by bisection; those still inside (the start was inside too) go to
        their clearance off their closest skin point.

        Parameters
        ----------
        start, end : (P, 3) float arrays
        target : (P,) float array
            Clearance (m).

        Returns
        -------
        points : (P, 3) float array
        closest : dict
            Their :meth:`SurfaceQuery.closest` result (distances of the points
            placed off the skin set to their target).
        """
        lo = np.zeros(len(start))  # fraction of the step known to be fine
        hi = np.ones(len(start))
        for _ in range(self.bisect_steps):
            mid = 0.5 * (lo + hi)
            d = self.query.closest(start + mid[:, None] * (end - start), ring=False)["distance"]
            ok = d >= np.minimum(target, 0.0005)
            lo = np.where(ok, mid, lo)
            hi = np.where(ok, hi, mid)
        out = start + lo[:, None] * (end - start)
        closest = self.query.closest(out)
        bad = closest["distance"] < 0
        out[bad] = off_skin(closest, bad, target[bad])
        closest["distance"][bad] = target[bad]
        return out, closest


def relax_stretch(plan_: DressPlan, body_points: np.ndarray, points: np.ndarray, item_edges: np.ndarray,
                  faces: np.ndarray, constraints: UntangleConstraints, detect: U.BadElements):
    """The edges the untangle left outside the body's own stretch range (its
    gradient field cannot be met across a seam between two body parts, and
    its constraints move single vertices again) brought back into it
    (:func:`untangle.relax_edges`, under the same constraints). Only edges
    outside the skin's own range can be outside the full range, which
    contains it: the full range is found for those and for the relaxed
    region only.

    Parameters
    ----------
    plan_ : DressPlan
    body_points : (N, 3) float array
    points : (M, 3) float array
        The untangled items.
    item_edges : (E, 2) int array
    faces : (F, 3) int array
    constraints : UntangleConstraints
    detect : untangle.BadElements

    Returns
    -------
    points : (M, 3) float array
    relaxed : (M,) bool array
    stats : dict
    """
    b = plan_.binding
    fixed = plan_.rigid_mask()
    vr = vertex_stretch(b.triangles, plan_.ref_body, body_points, b.faces)
    cand = np.flatnonzero(U.outside_range(plan_.ref_points, points, item_edges,
                                          *skin_range(item_edges, vr), fixed))
    if not len(cand):
        return points, np.zeros(len(points), dtype=bool), {}
    return U.relax_edges(plan_.ref_points, points, item_edges,
                         lambda idx: stretch_limits(plan_, body_points, item_edges[idx], vr),
                         plan_.mesh.neighbours, fixed, constraints, faces, lambda p: detect(p)[0], candidates=cand)


def keep_fit(plan_: DressPlan, query: SurfaceQuery, before: np.ndarray, after: np.ndarray, touched: np.ndarray,
             distance_before: np.ndarray | None = None):
    """The untangle must not trade the fit for shape: an item whose median
    clearance error (|clearance - reference clearance| over all its vertices,
    the dressing metric) grows by more than ``UNTANGLE_CLEARANCE_DRIFT`` gets
    its points from before the untangle back (a thin closed tube such as a
    necklace, freed as a whole, can otherwise slide around the neck). One
    query over the touched items before (unless known), one over the touched
    vertices after: the others kept their clearance.

    Parameters
    ----------
    plan_ : DressPlan
    query : SurfaceQuery
        On the current body.
    before, after : (M, 3) float arrays
        The items before and after the untangle; ``after`` is updated in place.
    touched : (M,) bool array
        The vertices the untangle moved; updated in place.
    distance_before : (M,) float array, optional
        Signed distances of ``before`` if known.

    Returns
    -------
    list of str
        The names of the items that got their points back.
    """
    spans = [(item, a, b) for item, a, b in zip(plan_.items, plan_.offsets[:-1], plan_.offsets[1:])
             if touched[a:b].any()]
    rows = np.concatenate([np.arange(a, b) for _, a, b in spans]) if spans else np.zeros(0, dtype=np.int64)
    d_before = np.zeros(len(before))
    if distance_before is not None:
        d_before[rows] = distance_before[rows]
    else:
        d_before[rows] = query.closest(before[rows])["distance"]
    d_after = d_before.copy()
    tv = np.flatnonzero(touched)
    d_after[tv] = query.closest(after[tv])["distance"]
    reverted = []
    for item, a, b in spans:
        ref_c = plan_.ref_clearance[a:b]
        err_before = np.median(np.abs(d_before[a:b] - ref_c))
        err_after = np.median(np.abs(d_after[a:b] - ref_c))
        if err_after > err_before + UNTANGLE_CLEARANCE_DRIFT:
            after[a:b] = before[a:b]
            touched[a:b] = False
            reverted.append(item.name)
    return reverted


def untangle_items(plan_: DressPlan, body_points: np.ndarray, pts: np.ndarray, query: SurfaceQuery,
                   target: np.ndarray, rigid_maps: list, bisect_steps: int = 5, relax: bool = True,
                   footprints: dict | None = None, **kw):
    """Run :func:`untangle.untangle` on redressed items.

    Vertex gradients from the binding (:func:`deformation_gradients`; rigid
    parts: their similarity), constraints = push-out to ``target`` and the
    layer order, both restricted to the re-solved vertices
    (:class:`UntangleConstraints`). With ``relax``, edges still outside the
    body's stretch range (:func:`stretch_limits`) are then brought back into
    it (:func:`relax_stretch`). Items whose fit the untangle worsened keep
    their input (:func:`keep_fit`).

    Parameters
    ----------
    plan_ : DressPlan
    body_points : (N, 3) float array
    pts : (M, 3) float array
        The redressed items.
    query : SurfaceQuery
        On ``body_points``.
    target : (M,) float array
        Clearance (m) to push out to; NaN = none.
    rigid_maps : list
        [(vertex indices (P,), linear map ``s * rot`` (3, 3))] per rigid group.
    bisect_steps : int
    relax : bool
    footprints : dict, optional
        The closest body points of ``pts`` (:meth:`SurfaceQuery.closest` keys
        distance, point, normal) if already known.
    **kw
        Options of :func:`untangle.untangle`.

    Returns
    -------
    points : (M, 3) float array
    touched : (M,) bool array
    stats : dict
    """
    grad = deformation_gradients(plan_, body_points, rigid_maps)
    faces, item_edges = plan_.mesh.faces, plan_.mesh.edges
    known = footprints is not None
    if plan_.layers and not known:
        res = query.closest(pts)
        work_footprints = {k: res[k] for k in ("distance", "point", "normal")}
    elif known:
        work_footprints = {k: v.copy() for k, v in footprints.items()}  # the constraints update them
    else:
        work_footprints = None
    constraints = UntangleConstraints(plan_, query, target, faces, grad, work_footprints, bisect_steps)
    detect = U.BadElements(plan_.ref_points, faces, item_edges, grad)
    new, touched, stats = U.untangle(plan_.ref_points, pts, faces, item_edges, plan_.mesh.neighbours, grad,
                                     constraints, detect=detect, **kw)
    if relax:
        new, relaxed, st = relax_stretch(plan_, body_points, new, item_edges, faces, constraints, detect)
        touched |= relaxed
        stats.update(st)
    stats["reverted_items"] = keep_fit(plan_, query, pts, new, touched,
                                       footprints["distance"] if known else None)
    return new, touched, stats


def stretch_limits(plan_: DressPlan, body_points: np.ndarray, item_edges: np.ndarray,
                   vertex_range: tuple | None = None):
    """(lo (E,), hi (E,)): the body's own stretch range (edge-length ratios,
    :func:`body_stretch.stretch_range`) of item edges (E, 2) (stacked
    indices) from the plan's reference body to ``body_points`` (N, 3), the
    range :func:`metrics.shape_change` judges them by; vertex_range:
    :func:`body_stretch.vertex_stretch` of the binding if already known."""
    b = plan_.binding
    return stretch_range(plan_.ref_points, item_edges, b.triangles, plan_.ref_body, body_points, b.faces,
                         plan_.ref_foot.triangle, plan_.ref_foot.bary, plan_.ref_clearance, vertex_range)
