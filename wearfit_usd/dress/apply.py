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
4. untangle folded or over-stretched patches (:func:`repair.untangle_items`);
5. optionally (``surface_layers``), keep outer layers over the inner
   items' triangles, not only their vertices
   (:class:`surface_layers.SurfaceLayers`), the moves spread and checked
   against the body once more.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..fit.body_fit import fit_character
from ..geometry.closest import SurfaceQuery, VertexNormals
from ..geometry.mesh import same_topology
from ..model import Character, Mesh
from ..progress import debug, info
from . import regions as R
from .binding import local_signed_distance
from .corrections import SPREAD_CLEARANCE_DRIFT, push_out, smoothstep, spread_corrections
from .layers import keep_layers
from .plan import DressPlan, plan
from .repair import release_misfits, untangle_items
from .surface_layers import SurfaceLayers


def fitted_body_points(ref: Character, target: Character) -> np.ndarray:
    """The reference body topology deformed onto the target (N_ref, 3), by
    :func:`fit.body_fit.fit_character`; for a target of the reference's
    topology (the fit's fast path: its own points) without the pose step,
    which would only pose the fitted skeleton dressing does not use
    (0.18 s a dress)."""
    r, t = ref.body, target.body
    same = same_topology(r.points, r.faces, t.points, t.faces)
    return np.asarray(fit_character(ref, target, {"pose_align": False} if same else None).points,
                      dtype=np.float64)


@dataclass
class DressResult:
    items: list[Mesh]          # redressed items (internal space), names/topology as the reference
    points: np.ndarray         # (M, 3) all item points stacked
    free_points: np.ndarray    # (M, 3) binding result before rigid parts and push-out
    moved: np.ndarray          # (M,) bool: changed by the penetration pass
    plan: DressPlan
    body_points: np.ndarray    # the fitted body (reference topology)
    timings: dict


@dataclass(frozen=True)
class PassOptions:
    """Options of the passes that correct an evaluated plan (see :func:`apply`).

    Attributes
    ----------
    margin : float
        m; vertices whose estimated clearance is below this get the exact
        penetration test.
    near_other : float
        m; so do those this close to a body vertex of another region than
        their own.
    push_inherited : bool
        Push vertices that were already deeper than ``inherited_clearance``
        inside the reference body out to that clearance.
    inherited_clearance : float
        m; see ``push_inherited``.
    spread : bool
        Spread the single-vertex corrections over the item mesh.
    untangle : bool
        Re-solve folded or over-stretched patches afterwards.
    surface_layers : bool
        Last, keep outer layers over the items under them surface against
        surface (:mod:`surface_layers`). Off by default: on the bind pose's
        dress it moved the long skirt on a man's body (``body_male_heavy``,
        the CMU walk: the redress's stretch p99 1.15 -> 1.39, the skinned
        copy's new penetrations 1.12 -> 1.53 %); ``animate`` runs the same
        pass on every frame instead.
    """
    margin: float = 0.003
    near_other: float = 0.03
    push_inherited: bool = False
    inherited_clearance: float = 0.001
    spread: bool = True
    untangle: bool = True
    surface_layers: bool = False


class Evaluation(NamedTuple):
    """The plan evaluated on a body, before any correction."""
    free: np.ndarray        # (M, 3) the binding's result
    points: np.ndarray      # (M, 3) with the rigid parts placed and the loose parts smoothed
    rigid_maps: list        # [(vertex indices (P,), linear part s * rot (3, 3))] per rigid group


class Candidates(NamedTuple):
    """The vertices the penetration pass tests, and the clearance estimates that chose them."""
    mask: np.ndarray        # (M,) bool: vertices to test exactly
    local: np.ndarray       # (M,) signed distance to the vertex's own bound triangles (m)
    estimate: np.ndarray    # (M,) clearance through the nearest body vertex and its normal (m)


class Corrected(NamedTuple):
    """Item points after a correction pass."""
    points: np.ndarray      # (M, 3)
    moved: np.ndarray       # (M,) bool: vertices the pass moved


class Placed(NamedTuple):
    """Item rows the caller places itself: they replace the plan's evaluation
    and no correction pass moves them; the other items are corrected against
    them (an outer layer over them). A shot's first pose is dressed with its
    skinned rigid items where the shot's frame 0 puts them (see
    :func:`animate.try_on.animate`)."""
    rows: np.ndarray        # (R,) int: stacked item rows
    points: np.ndarray      # (R, 3) their points


class Applied(NamedTuple):
    """The result of :func:`apply`."""
    points: np.ndarray      # (M, 3) the dressed item points
    free: np.ndarray        # (M, 3) the binding's result before rigid parts and corrections
    moved: np.ndarray       # (M,) bool: vertices the correction passes moved
    timings: dict           # seconds per step


class Footprints:
    """The closest body points of item points, kept current by re-querying only
    the vertices that moved since their footprint was taken (:meth:`refresh`).

    Parameters
    ----------
    query : SurfaceQuery
        On the current body.
    points : (M, 3) float array
        Item points.

    Attributes
    ----------
    closest : dict
        :meth:`SurfaceQuery.closest` keys ``distance`` (M,), ``point`` (M, 3),
        ``normal`` (M, 3); the form :func:`layers.keep_layers` and
        :func:`repair.untangle_items` take.
    """

    KEYS = ("distance", "point", "normal")

    def __init__(self, query: SurfaceQuery, points: np.ndarray):
        res = query.closest(points)
        self.query = query
        self.closest = {k: res[k] for k in self.KEYS}
        self._taken_at = points.copy()

    def refresh(self, points: np.ndarray) -> None:
        """Re-query the vertices that moved.

        Parameters
        ----------
        points : (M, 3) float array
            The item points now.
        """
        sv = np.flatnonzero((points != self._taken_at).any(axis=1))
        res = self.query.closest(points[sv])
        for k in self.closest:
            self.closest[k][sv] = res[k]
        self._taken_at[sv] = points[sv]


def skirt_heights(plan_: DressPlan, body_points: np.ndarray, free: np.ndarray) -> tuple:
    """Heights of the skirt parts on ``body_points``: each keeps its shape's
    height over the floor, in proportion to its top's.

    MakeHuman's own helper skirt, deformed by a body shape's targets, is a
    height-scaled copy of itself over the floor: on the 13 % shorter body
    its top went 13.3 cm down and its hem stayed 11 cm over the floor. The
    binding places a skirt from the hips, which keeps its length; lengthened
    as the legs' edges were (and then smoothed) its hem came 4.5 cm lower
    than the helper's there. Here each item's skirt rows (bound to the hips,
    ``regions.bind == HIPS``) get

        y' = f' + k (y - f),    k = (top' - f') / (top - f),

    with ``y`` its height on the plan's reference, ``f`` and ``f'`` the
    lowest leg vertex (the floor) on the reference and on ``body_points``,
    and ``top``, ``top'`` the item's highest vertex on the reference and as
    bound (``free``) on ``body_points``, blended from the binding's height
    at the item's top to ``y'`` at the crotch and below (a smoothstep in the
    reference height: over the hips the binding follows their shape; with
    ``y'`` everywhere the long skirt's walk on body_female_heavy had stretch
    max 4.2x against 2.4x); x and z stay the binding's. Against MakeHuman's
    helper on the same shapes, p95: thin 17.7 -> 14.6 mm, heavy 21.4 -> 22.2
    mm, short 45.7 -> 23.6 mm (the rest is the width: the binding keeps the
    clearance to the legs where the helper narrows or widens less).

    Parameters
    ----------
    plan_ : DressPlan
    body_points : (N, 3) float array
        Of the plan's body topology (internal space, y up).
    free : (M, 3) float array
        The binding's points on it.

    Returns
    -------
    (rows (R,) int64, heights (R,) float64): the skirt rows and their y; empty
    without skirt parts or leg regions.
    """
    skirt = plan_.regions.bind == R.HIPS
    legs = np.isin(plan_.regions.body, (R.LEFT_LEG, R.RIGHT_LEG)) if plan_.regions.body is not None else None
    if not skirt.any() or legs is None or not legs.any():
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    f0 = float(np.min(plan_.ref_body[legs, 1]))
    f1 = float(np.min(np.asarray(body_points)[legs, 1]))
    torso = plan_.regions.body == R.TORSO
    crotch0 = float(np.min(plan_.ref_body[torso, 1])) if torso.any() else -np.inf
    rows, heights = [], []
    for sl in plan_.item_slices():
        r = np.flatnonzero(skirt[sl]) + sl.start
        top0 = float(np.max(plan_.ref_points[sl, 1]))
        if len(r) == 0 or top0 - f0 <= 1e-6:
            continue
        k = (float(np.max(free[sl, 1])) - f1) / (top0 - f0)
        rows.append(r)
        y0 = plan_.ref_points[r, 1]
        # from the binding's heights at the top to the scaled copy's from the
        # crotch down (over the hips the binding's follow their shape)
        share = smoothstep((top0 - y0) / max(top0 - crotch0, 1e-6))
        heights.append(free[r, 1] + share * (f1 + k * (y0 - f0) - free[r, 1]))
    if not rows:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    return np.concatenate(rows), np.concatenate(heights)


def evaluate(plan_: DressPlan, body_points: np.ndarray, skirt_heights_kept: bool = False) -> Evaluation:
    """The plan on a body, before any correction: the binding, the rigid parts
    placed by their similarity transforms, the loose parts smoothed
    (:class:`corrections.LooseSmoother`).

    Parameters
    ----------
    plan_ : DressPlan
    body_points : (N, 3) float array
        Body points of the plan's body topology.
    skirt_heights_kept : bool
        Skirt parts keep their height over the floor in proportion to their
        top's (:func:`skirt_heights`; for another body shape, not for the
        reference posed); the loose parts' smoothing then diffuses the
        displacement from that shape (diffusing a height scale flattens it
        at the ends: the hem was 1.5 cm lower).

    Returns
    -------
    Evaluation
        free (M, 3), points (M, 3), rigid_maps.
    """
    free = plan_.binding.evaluate(body_points)
    smooth_from = plan_.ref_points
    if skirt_heights_kept:
        rows, heights = skirt_heights(plan_, body_points, free)
        if len(rows):
            free[rows, 1] = heights
            smooth_from = plan_.ref_points.copy()
            smooth_from[rows, 1] = heights
    pts = free.copy()
    rigid_maps = []
    if plan_.rigid_groups:
        parts = plan_.rigid_parts
        s, rot, t = parts.transforms(body_points)
        parts.place(s, rot, t, pts)
        rigid_maps = [(gv, s[i] * rot[i]) for i, gv in enumerate(parts.groups)]
    pts = plan_.smoother(pts, smooth_from, body_points, plan_.ref_body)
    return Evaluation(free, pts, rigid_maps)


def clearance_targets(plan_: DressPlan, push_inherited: bool, inherited_clearance: float) -> np.ndarray:
    """The clearance each vertex is pushed out to if found inside the body.

    The reference clearance where the vertex was outside the reference body;
    with ``push_inherited``, ``inherited_clearance`` where it was deeper than
    that inside it (skin showing through); shallower ones lie on the skin
    (eyebrows) and are left alone. Rigid parts keep their authored insets (a
    shoe's insole 0.5-5 mm inside the foot sole, hair-card roots under the
    scalp): they move as a whole, and pushing single vertices of them out to
    the surface is what bent them (every over-stretched shoe and short-hair
    edge on the reference-shaped CMU-rig body came from it); they are still
    pushed out where they newly penetrate.

    Parameters
    ----------
    plan_ : DressPlan
    push_inherited : bool
    inherited_clearance : float
        m.

    Returns
    -------
    (M,) float array
        Clearance (m); NaN = leave the vertex where it is.
    """
    inherited = push_inherited & (plan_.ref_clearance < -inherited_clearance)
    # (the plan's rigid parts, also when released on this body)
    inherited &= ~plan_.insets_kept
    return np.where(plan_.ref_clearance > 0, plan_.ref_clearance,
                    np.where(inherited, inherited_clearance, np.nan))


def penetration_candidates(plan_: DressPlan, body_points: np.ndarray, body_faces: np.ndarray, points: np.ndarray,
                           margin: float, near_other: float) -> Candidates:
    """The item vertices that may be inside the body: only these get the exact
    signed-distance query.

    A cheap local test against each vertex's own bound triangles picks those
    close to (or inside) them, or close to another body region (a posed limb
    pressing into the torso...); a bulge of the same region (a heavier belly
    or thigh under a loose skirt) is far from the vertex's own triangles, so
    the clearance is also estimated through the nearest body vertex and its
    normal.

    Parameters
    ----------
    plan_ : DressPlan
    body_points : (N, 3) float array
    body_faces : (T, 3) int array
    points : (M, 3) float array
        Item points.
    margin : float
        m; vertices whose estimated clearance is below this are candidates.
    near_other : float
        m; so are those this close to a body vertex of another region.

    Returns
    -------
    Candidates
        mask (M,) bool, local (M,) and estimate (M,) clearances (m).
    """
    d_loc, _ = local_signed_distance(plan_.binding, body_points, points)
    cand = d_loc < margin
    dn, vn = cKDTree(body_points).query(points, k=1)
    cand |= (plan_.regions.body[vn] != plan_.regions.vertex) & (dn < near_other)
    normals = VertexNormals(body_faces, len(body_points))(body_points)
    est = np.einsum("ij,ij->i", points - body_points[vn], normals[vn])
    cand |= est < margin
    return Candidates(cand, d_loc, est)


def ring_neighbours(plan_: DressPlan, spread: bool) -> sp.csr_matrix:
    """The adjacency :func:`corrections.push_out` smooths the 1-ring of pushed
    vertices over.

    Parameters
    ----------
    plan_ : DressPlan
    spread : bool
        If set, only the rigid parts' adjacency (the other corrections are
        spread by :func:`spread_pass` instead); else the whole item mesh's.

    Returns
    -------
    (M, M) sparse matrix
    """
    neighbours = plan_.mesh.neighbours
    if not spread:
        return neighbours
    rig = plan_.rigid_mask()
    return (sp.diags(rig.astype(np.float64)) @ neighbours @ sp.diags(rig.astype(np.float64))
            + sp.diags((~rig).astype(np.float64))).tocsr()


def push_out_pass(plan_: DressPlan, query: SurfaceQuery, points: np.ndarray, target: np.ndarray,
                  candidates: np.ndarray, ring: sp.spmatrix) -> Corrected:
    """Push the candidates found inside the body out to their target clearance
    (:func:`corrections.push_out`); where that moved loose parts, spread the
    push over their neighbourhood (a smooth bulge, not a spike) and push out
    what went back inside.

    Parameters
    ----------
    plan_ : DressPlan
    query : SurfaceQuery
        On the current body.
    points : (M, 3) float array
    target : (M,) float array
        :func:`clearance_targets`.
    candidates : (M,) bool array
        The vertices to test.
    ring : (M, M) sparse matrix
        :func:`ring_neighbours`.

    Returns
    -------
    Corrected
        points (M, 3), moved (M,) bool.
    """
    pts, moved = push_out(query, points, target, mask=candidates, neighbours=ring)
    if np.any(moved & (plan_.looseness > 0)):
        body = query.points if query.points is not None and len(query.points) == len(plan_.ref_body) else None
        pts = plan_.smoother(pts, plan_.ref_points, body, plan_.ref_body)
        again = candidates | moved
        pts, moved_again = push_out(query, pts, target, mask=again, neighbours=ring)
        moved |= moved_again
    return Corrected(pts, moved)


def spread_pass(plan_: DressPlan, before: np.ndarray, single: np.ndarray, moved: np.ndarray) -> Corrected:
    """Single-vertex corrections spread smoothly over the item mesh
    (:func:`corrections.spread_corrections`, rigid parts excluded): alone they
    stretch every edge at them.

    An item the spread would move as a whole (a thin necklace lifted over a
    shirt) keeps the single-vertex corrections: the spread may change its
    median clearance by at most ``SPREAD_CLEARANCE_DRIFT`` (its extra
    displacement bounds the clearance change).

    Parameters
    ----------
    plan_ : DressPlan
    before : (M, 3) float array
        The points before the corrections.
    single : (M, 3) float array
        The points after them.
    moved : (M,) bool array
        The corrected vertices (any other that changed counts too).

    Returns
    -------
    Corrected
        points (M, 3), moved (M,) bool: the vertices the spread moved.
    """
    req = moved | (np.abs(single - before).max(axis=1) > 1e-6)
    pts, spread_v = spread_corrections(plan_.ref_points, before, single, req, plan_.mesh.neighbours,
                                       fixed=plan_.rigid_mask())
    extra = np.linalg.norm(pts - single, axis=1)
    for a, b in zip(plan_.offsets[:-1], plan_.offsets[1:]):
        if spread_v[a:b].any() and np.median(extra[a:b]) > SPREAD_CLEARANCE_DRIFT:
            pts[a:b] = single[a:b]
            spread_v[a:b] = False
    return Corrected(pts, spread_v)


def recheck_spread(plan_: DressPlan, query: SurfaceQuery, before: np.ndarray, spread: Corrected,
                   target: np.ndarray, candidates: Candidates, margin: float,
                   footprints: Footprints | None) -> Corrected:
    """The vertices a spread moved, checked once more: only those it moved by
    more than their estimated clearance (less the margin) can have gone inside
    the body (pushed out again), and the outer layers among them are kept over
    the items under them.

    Parameters
    ----------
    plan_ : DressPlan
    query : SurfaceQuery
        On the current body.
    before : (M, 3) float array
        The points before any correction.
    spread : Corrected
        :func:`spread_pass`'s result.
    target : (M,) float array
        :func:`clearance_targets`.
    candidates : Candidates
        Their clearance estimates.
    margin : float
        m.
    footprints : Footprints or None
        Refreshed here; None only for a plan without layers.

    Returns
    -------
    Corrected
        points (M, 3), moved (M,) bool (the spread's vertices included).
    """
    shift = np.linalg.norm(spread.points - before, axis=1)
    check = spread.moved & (np.minimum(candidates.local, candidates.estimate) < shift + margin)
    # and their neighbours: tested alone, one side of a narrow strip of
    # triangles (a crotch seam between the thighs of a crouch) was pushed
    # 22 mm out of a thigh while the other, 0.5 mm away, stayed
    check |= (plan_.mesh.neighbours @ check.astype(np.float64)) > 0
    pts, pushed = push_out(query, spread.points, target, mask=check)
    moved = spread.moved | pushed
    if plan_.layers:
        footprints.refresh(pts)
        pts, lifted = keep_layers(query, pts, plan_.offsets, plan_.layers, mask=spread.moved,
                                  footprints=footprints.closest)
        moved |= lifted
    return Corrected(pts, moved)


def correct_penetrations(plan_: DressPlan, body_points: np.ndarray, body_faces: np.ndarray, query: SurfaceQuery,
                         points: np.ndarray, target: np.ndarray, options: PassOptions,
                         fixed: np.ndarray | None = None):
    """The penetration and layer passes on evaluated item points.

    Vertices found inside the body are pushed out to their target clearance,
    outer layers kept over the items under them (:func:`layers.keep_layers`),
    and with ``options.spread`` these single-vertex corrections are spread
    over the item mesh and checked again.

    Parameters
    ----------
    plan_ : DressPlan
    body_points : (N, 3) float array
    body_faces : (T, 3) int array
    query : SurfaceQuery
        On ``body_points``.
    points : (M, 3) float array
        :func:`evaluate`'s points.
    target : (M,) float array
        :func:`clearance_targets`.
    options : PassOptions
    fixed : (M,) bool array, optional
        Vertices neither pushed out nor lifted over a layer (:class:`Placed`).

    Returns
    -------
    corrected : Corrected
        points (M, 3), moved (M,) bool.
    footprints : Footprints or None
        Of the corrected points; None when the plan has no layers.
    """
    cand = penetration_candidates(plan_, body_points, body_faces, points, options.margin, options.near_other)
    if fixed is not None:
        cand = cand._replace(mask=cand.mask & ~fixed)
    debug(f"penetration pass: {int(cand.mask.sum())} of {len(cand.mask)} vertices tested")
    # with ``spread`` the per-vertex corrections are made alone and then
    # spread over the item mesh, which replaces push_out's light smoothing
    # of the 1-ring (rigid parts, not spread, keep it)
    pts, moved = push_out_pass(plan_, query, points, target, cand.mask, ring_neighbours(plan_, options.spread))
    footprints = None
    if plan_.layers:
        # layers keep their order: an outer item stays over the item under it
        footprints = Footprints(query, pts)
        pts, lifted = keep_layers(query, pts, plan_.offsets, plan_.layers, footprints=footprints.closest,
                                  mask=None if fixed is None else ~fixed)
        moved |= lifted
    if options.spread:
        spread = spread_pass(plan_, points, pts, moved)
        pts = spread.points
        if spread.moved.any():
            rechecked = recheck_spread(plan_, query, points, spread, target, cand, options.margin, footprints)
            pts = rechecked.points
            moved |= rechecked.moved
    if footprints is not None:
        footprints.refresh(pts)  # for the untangle
    return Corrected(pts, moved), footprints


def apply(plan_: DressPlan, body_points: np.ndarray, body_faces: np.ndarray, penetration: bool = True,
          query: SurfaceQuery | None = None, options: PassOptions | None = None,
          skirt_heights_kept: bool = False, placed: Placed | None = None) -> Applied:
    """Evaluate a plan on fitted body points and, with ``penetration``, correct
    the result.

    Vertices that end inside the body but were outside the reference body
    are pushed out to their reference clearance. Those that were inside the
    reference body already keep their (negative) reference clearance, as
    every other vertex does: dressing the reference onto its own shape gives
    the reference back. With ``options.push_inherited`` the ones deeper than
    ``options.inherited_clearance`` are pushed out to that clearance instead
    (a flaw of the asset, e.g. a tight suit fitted by MakeHuman, which hides
    the skin under clothes with ``delete_verts``: the skin would show
    through); this repair flattens folds that dip into the body and so
    shortens their edges. Vertices of the plan's rigid groups always keep
    such authored insets (they move as a whole; a shoe's insole stays inside
    the sole also where :func:`repair.release_misfits` freed the shoe on this
    body).

    With ``options.spread`` the penetration and layer corrections (single
    vertices) are spread smoothly over the item mesh
    (:func:`corrections.spread_corrections`, every vertex at least as far as
    its own correction; rigid parts excluded) instead of only smoothing their
    1-ring. With ``options.untangle`` the neighbourhoods of folded item
    triangles and badly stretched edges are then re-solved so they deform like
    the body under them, under the same constraints
    (:func:`repair.untangle_items`).

    Parameters
    ----------
    plan_ : DressPlan
    body_points : (N, 3) float array
        The fitted body, of the plan's body topology.
    body_faces : (T, 3) int array
        Its triangles (only used with ``penetration`` and no ``query``).
    penetration : bool
        Run the correction passes.
    query : SurfaceQuery, optional
        On ``body_points``, if already built.
    options : PassOptions, optional
        Default ``PassOptions()``.
    skirt_heights_kept : bool
        See :func:`evaluate`.
    placed : Placed, optional
        Rows placed by the caller: they replace the evaluation and no pass
        moves them.

    Returns
    -------
    Applied
        points (M, 3), free points (M, 3) (the binding alone), moved (M,) bool,
        timings dict.
    """
    options = options or PassOptions()
    n_items = plan_.binding.n_items
    if placed is not None and (np.shape(placed.points) != (len(placed.rows), 3) or
                               (len(placed.rows) and not 0 <= np.min(placed.rows) <= np.max(placed.rows) < n_items)):
        raise ValueError(f"placed: {len(placed.rows)} rows of {n_items} item points with points "
                         f"{np.shape(placed.points)}: expected rows in range and points (rows, 3)")
    t0 = time.perf_counter()
    ev = evaluate(plan_, body_points, skirt_heights_kept)
    t1 = time.perf_counter()
    pts, moved = ev.points, np.zeros(len(ev.points), dtype=bool)
    fixed = None
    if placed is not None:
        pts[placed.rows] = placed.points
        fixed = np.zeros(len(pts), dtype=bool)
        fixed[placed.rows] = True
    if penetration:
        if query is None:
            query = SurfaceQuery(body_faces, body_points)
        target = clearance_targets(plan_, options.push_inherited, options.inherited_clearance)
        (pts, moved), footprints = correct_penetrations(plan_, body_points, body_faces, query, ev.points,
                                                        target, options, fixed)
    t2 = time.perf_counter()
    timings = {"evaluate_s": t1 - t0, "penetration_s": t2 - t1}
    if penetration and options.untangle:
        pts, touched, stats = untangle_items(plan_, body_points, pts, query, target, ev.rigid_maps,
                                             footprints=footprints.closest if footprints is not None else None)
        moved |= touched
        timings["untangle_s"] = time.perf_counter() - t2
        debug(f"untangle: {stats}")
    if penetration and options.surface_layers and plan_.layers:
        # the inner layers' triangles between their vertices, which the
        # vertex-to-vertex layer pass cannot see (a coarse skirt's waistband
        # through a top's hem)
        t3 = time.perf_counter()
        movable = ~plan_.rigid_mask() if fixed is None else ~plan_.rigid_mask() & ~fixed
        surface = SurfaceLayers(plan_.layers, plan_.offsets, plan_.mesh.faces, body_faces, body_points, pts,
                                movable=movable, rigid_inner=plan_.rigid_item_rows())
        single = surface(body_points, pts)
        if surface.pushed.any():
            # spread smoothly once more (without it, single lifts and pulls
            # left edges stretched 2x in a first pose's dress on GDQuest's
            # mannequin), and whatever the spread carried into the body out
            lifted = spread_pass(plan_, pts, single, surface.pushed) if options.spread else None
            spread_pts = single if lifted is None else lifted.points
            check = surface.pushed if lifted is None else surface.pushed | lifted.moved
            pts, again = push_out(query, spread_pts, target, mask=check)
            moved |= check | again
        timings["surface_layers_s"] = time.perf_counter() - t3
    if placed is not None:  # the spread and the untangle leave no trace on them either
        pts[placed.rows] = placed.points
        moved[placed.rows] = False
    return Applied(pts, ev.free, moved, timings)


def push_out_target(plan_: DressPlan, body: Mesh, points: np.ndarray, push_inherited: bool = False) -> Corrected:
    """Item points pushed out of the target's own surface, for a target of
    another topology than the reference.

    The passes of :func:`apply` keep the items outside the fitted body (the
    reference topology deformed onto the target); where that fit leaves the
    target's surface outside it (a coarse game body's flat facets, a remeshed
    scan's merged fingers) the items are inside the target. Vertices found
    inside it that were outside the reference body go out to their
    reference clearance (:func:`corrections.push_out`), the pushes spread
    over the item mesh (:func:`spread_pass`) and checked once more;
    rigid parts keep their authored insets, as in :func:`clearance_targets`.

    Parameters
    ----------
    plan_ : DressPlan
    body : Mesh
        The target body.
    points : (M, 3) float array
        The dressed item points.
    push_inherited : bool
        See :class:`PassOptions`.

    Returns
    -------
    Corrected
        points (M, 3), moved (M,) bool.
    """
    target = clearance_targets(plan_, push_inherited, PassOptions().inherited_clearance)
    query = SurfaceQuery(body.faces, body.points)
    pushed, moved = push_out(query, points, target, neighbours=ring_neighbours(plan_, True))
    if not moved.any():
        return Corrected(pushed, moved)
    # spread over the item mesh (single-vertex pushes fold and stretch it), then once more
    spread = spread_pass(plan_, points, pushed, moved)
    pts, again = push_out(query, spread.points, target, mask=spread.moved | moved)
    return Corrected(pts, moved | spread.moved | again)


def dress(ref: Character, target: Character, k: int = 5, use_regions: bool = True,
          rigid="auto", penetration: bool = True, body_points: np.ndarray | None = None,
          strict_far: bool = False, push_inherited: bool = False, untangle: bool = True,
          prepared: DressPlan | None = None, placed: Placed | None = None,
          surface_layers: bool = False) -> DressResult:
    """Put every item of ``ref`` on ``target``'s body (internal space).
    ``k``, ``use_regions``, ``rigid``, ``strict_far``: see :func:`plan.plan`;
    ``push_inherited``, ``untangle``, ``surface_layers``: see :class:`PassOptions`. ``prepared``: a plan
    of ``ref`` made earlier (e.g. :meth:`DressPlan.rebound`, or :func:`plan.plan`
    with its other options), used instead of a new one (the plan options are
    then ignored). ``body_points``: the reference body fitted onto the target
    (N_ref, 3) if already known (default :func:`fitted_body_points`).
    ``placed``: item rows placed by the caller (:class:`Placed`)."""
    tb = time.perf_counter()
    if body_points is None:
        body_points = fitted_body_points(ref, target)
    t_fit = time.perf_counter() - tb
    if prepared is not None:
        p = prepared
    else:
        p = plan(ref, k=k, use_regions=use_regions, rigid=rigid, strict_far=strict_far)
    # the plan's reference-body query has this topology
    query = p.body_query.moved_to(body_points) if penetration else None
    if penetration and p.rigid_groups:
        p, released = release_misfits(p, body_points, query)
        if released:
            info(f"{target.source}: rigid parts that do not fit this body move freely: {', '.join(released)}")
    # a skirt keeps its height over the floor in proportion to its top's
    pts, free, moved, tm = apply(p, body_points, ref.body.faces, penetration=penetration, query=query,
                                 options=PassOptions(push_inherited=push_inherited, untangle=untangle,
                                                     surface_layers=surface_layers),
                                 skirt_heights_kept=True, placed=placed)
    if penetration and not np.array_equal(target.body.faces, ref.body.faces):
        pts, on_target = push_out_target(p, target.body, pts, push_inherited)
        moved |= on_target
        if placed is not None:
            pts[placed.rows] = placed.points
            moved[placed.rows] = False
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
