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
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from . import regions as R
from .binding import Binding, bind, local_signed_distance, rebind
from .body_stretch import skin_range, stretch_range, vertex_stretch
from ..geometry.closest import SurfaceQuery, VertexNormals
from ..geometry.mesh import adjacency, components, edges, similarity_fit
from ..errors import GeometryError, InputError
from ..model import Character, Mesh
from ..progress import debug, info, warn
from .rigid_parts import RigidParts
from .corrections import (LOOSE_FULL, LOOSE_ITERATIONS, LOOSE_START, SPREAD_CLEARANCE_DRIFT, SPREAD_LENGTH,  # noqa: F401
                          SPREAD_RINGS, LooseSmoother, looseness, off_skin, push_out, spread_corrections)
from .layers import LAYER_MIN_GAP, LAYER_RADIUS, keep_layers, layer_gaps, layer_order, layer_pairs  # noqa: F401

FAR_FROM_BODY = 0.5  # m: items farther than this from the body are suspicious


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


# --------------------------------------------------------------------------
# dressing

def _group_mask(groups: list, m: int) -> np.ndarray:
    """(m,) bool: the vertices of rigid groups [(vertex indices, ...)]."""
    mask = np.zeros(m, dtype=bool)
    for gv, *_ in groups:
        mask[gv] = True
    return mask


@dataclass
class DressPlan:
    """Everything topology-dependent, built once on the reference body.

    binding: one :class:`Binding` for all item vertices (stacked in item order).
    offsets: (n_items + 1,) start of each item's rows.
    ref_clearance: (M,) signed clearance on the reference body.
    labels: (M,) body region each vertex is bound to.
    rigid_groups: list of (vertex indices (P,), body vertex indices (Q,),
        body vertex weights (Q,)) moved by one similarity transform.
    neighbours: (M, M) item adjacency (all items, block diagonal).
    looseness: (M,) 0..1, how much each vertex's displacement is smoothed
        over the item mesh (see :class:`LooseSmoother`): 0 for tight parts
        (clearance kept exactly), 1 for parts hanging far from the body.
    """
    items: list[Mesh]
    binding: Binding
    offsets: np.ndarray
    ref_points: np.ndarray
    ref_clearance: np.ndarray
    labels: np.ndarray
    tri_labels: np.ndarray
    body_labels: np.ndarray
    ref_body: np.ndarray | None = None
    rigid_groups: list = field(default_factory=list)
    rigid_parts: RigidParts | None = field(init=False, default=None)  # rigid_groups' per-frame evaluator
    rigid_items: list = field(default_factory=list)
    skirt_items: list = field(default_factory=list)
    neighbours: sp.csr_matrix | None = None
    looseness: np.ndarray | None = None
    smoother: "LooseSmoother | None" = None
    bind_labels: np.ndarray | None = None   # (M,) regions used for binding (skirt parts: HIPS)
    layers: list | None = None  # [(outer item, inner item, separation (n_outer,) m, inner vertex (n_outer,))]: :func:`layer_gaps`
    item_faces: np.ndarray | None = None  # (F, 3) triangles of all items, stacked vertex indices
    item_edges: np.ndarray | None = None  # (E, 2) their unique edges
    ref_foot: tuple | None = None  # (triangle (M,), barycentrics (M, 3)): closest reference skin point
    body_query: SurfaceQuery | None = field(default=None, repr=False, compare=False)  # on ref_body
    insets_kept: np.ndarray | None = None  # (M,) bool: keep authored insets (the plan's rigid parts)
    timings: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.rigid_groups:
            self.rigid_parts = RigidParts(self.rigid_groups, self.ref_body, self.ref_points)

    def rigid_mask(self) -> np.ndarray:
        """(M,) bool: item vertices of the rigid groups."""
        return _group_mask(self.rigid_groups, len(self.ref_points))

    def item_slices(self):
        return [slice(int(a), int(b)) for a, b in zip(self.offsets[:-1], self.offsets[1:])]

    def rebound(self, body_points: np.ndarray, item_points: np.ndarray) -> "DressPlan":
        """This plan with the items bound where they are now, item_points
        (M, 3), on body_points (N, 3) of the same body topology: the same
        triangles and weights (:func:`binding.rebind`), regions, clearances
        to keep, rigid groups, smoother and layers. Milliseconds instead of
        a new :func:`plan`; evaluating the result on ``body_points`` gives
        ``item_points`` back."""
        pts = np.ascontiguousarray(item_points, dtype=np.float64)
        body = np.ascontiguousarray(body_points, dtype=np.float64)
        items = [m.copy_with_points(pts[sl]) for m, sl in zip(self.items, self.item_slices())]
        return replace(self, items=items, binding=rebind(self.binding, body, pts), ref_points=pts,
                       ref_body=body, timings={})


def item_labels(ref_body: Mesh, body_labels: np.ndarray, tri_labels: np.ndarray, items: list[Mesh], points: np.ndarray,
                offsets: np.ndarray, centroid_tree: cKDTree):
    """Region per item vertex (of its nearest triangle), with skirt-like item
    parts (item edges joining a left-leg vertex to a right-leg vertex) moved
    to the torso. Returns (labels (M,), names of items treated as skirts)."""
    _, near = centroid_tree.query(points, k=1)
    labels = tri_labels[near].copy()
    torso = body_labels == R.TORSO
    crotch_y = float(ref_body.points[torso, 1].min()) if torso.any() else -np.inf
    skirts = []
    for item, a, b in zip(items, offsets[:-1], offsets[1:]):
        lab = labels[a:b]
        e = edges(item.faces)
        la, lb = lab[e[:, 0]], lab[e[:, 1]]
        cross = ((la == R.LEFT_LEG) & (lb == R.RIGHT_LEG)) | ((la == R.RIGHT_LEG) & (lb == R.LEFT_LEG))
        if not cross.any():
            continue
        comp = components(item.faces, item.n_points)
        # trousers touch left and right leg only at the crotch; a skirt joins
        # them all the way down to its hem: count joining edges clearly below
        # the crotch (the lowest torso-region body vertex)
        ymid = 0.5 * (points[a + e[cross, 0], 1] + points[a + e[cross, 1], 1])
        low = ymid < crotch_y - 0.08
        n_cross = np.bincount(comp[e[cross, 0]][low], minlength=comp.max() + 1)
        bridged = np.flatnonzero(n_cross >= 3)
        if len(bridged) == 0:
            continue
        sel = np.isin(comp, bridged) & ((lab == R.LEFT_LEG) | (lab == R.RIGHT_LEG) | (lab == R.TORSO))
        lab[sel] = R.HIPS
        labels[a:b] = lab
        skirts.append(item.name)
    return labels, skirts


def _auto_rigid(item: Mesh, ref_clear: np.ndarray, lab: np.ndarray, comp: np.ndarray,
                max_size: float, min_clearance: float, max_vertices: int):
    """Vertex groups (lists of local indices) of an item that should move
    rigidly: small (bounding-box diagonal <= max_size), not skin-tight
    (median clearance >= min_clearance) parts lying in one body region."""
    groups = []
    for region in np.unique(lab):
        sel = lab == region
        # whole components only: a component split across regions stays free
        comps = np.unique(comp[sel])
        whole = [c for c in comps if np.all(lab[comp == c] == region)]
        if not whole:
            continue
        v = np.flatnonzero(np.isin(comp, whole))
        pts = item.points[v]
        size = float(np.linalg.norm(pts.max(0) - pts.min(0)))
        if (len(v) <= max_vertices and size <= max_size
                and float(np.median(ref_clear[v])) >= min_clearance):
            groups.append(v)
    return groups


def plan(ref: Character, k: int = 5, use_regions: bool = True, rigid="auto",
         rigid_max_size: float = 0.4, rigid_min_clearance: float = 0.004,
         rigid_max_vertices: int = 4000, far: float = FAR_FROM_BODY,
         strict_far: bool = False, bind_labels: np.ndarray | None = None,
         skirt_items: list[str] | None = None,
         ref_clearance: np.ndarray | None = None) -> DressPlan:
    """Bind every item of ``ref`` to its body (done once per reference).

    bind_labels / skirt_items: the region of each item vertex (and the skirt
        items) from an earlier plan, e.g. of the reference in its rest pose.
        Regions are best told apart with the limbs away from the body: a posed
        body (hands hanging beside a skirt) would hand skirt vertices to the
        arms. Default: found on this body.
    ref_clearance: (M,) clearance each item vertex keeps (signed distance to
        the body it was authored on); default: measured on ``ref``. A posed
        reference passes its rest-pose clearance: posing moves rigid parts
        (a shoe over bending toes) through the skin, which is no reason to
        leave them there.

    rigid: "auto" (small stiff parts, see :func:`_auto_rigid`), "none", or a
        list of item names moved rigidly as a whole (per body region).
    """
    t0 = time.perf_counter()
    items = list(ref.items)
    if not items:
        raise InputError(ref.source, "the reference holds no wearable items (no Mesh besides the body)")
    body = ref.body
    offsets = np.concatenate([[0], np.cumsum([m.n_points for m in items])])
    pts = np.concatenate([m.points for m in items])
    tri = body.points[body.faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    degenerate = area2 <= 1e-10 * max(float(np.median(area2)), 1e-300)
    if degenerate.all():
        raise GeometryError(ref.source, "every body triangle is degenerate (zero area)")
    if degenerate.any():
        warn(f"{ref.source}: {int(degenerate.sum())} degenerate body triangles are not used for binding")
    centroids = tri.mean(axis=1)
    good = np.flatnonzero(~degenerate)
    tree = cKDTree(centroids[good])

    if use_regions and ref.skeleton is not None and body.joint_indices is not None:
        shares = R.region_shares(body, ref.skeleton)
        body_labels = np.argmax(shares, axis=1)
        leg_share = shares[:, R.LEFT_LEG] + shares[:, R.RIGHT_LEG]
    else:
        body_labels = np.zeros(body.n_points, dtype=np.int64)
        leg_share = np.zeros(body.n_points)
    tri_labels = R.triangle_regions(body.faces, body_labels)
    if bind_labels is None:
        labels, skirts = item_labels(body, body_labels, tri_labels[good], items, pts, offsets, tree)
    else:
        if len(bind_labels) != len(pts):
            raise ValueError(f"bind_labels has {len(bind_labels)} entries for {len(pts)} item vertices")
        labels, skirts = np.asarray(bind_labels).copy(), list(skirt_items or [])
    t1 = time.perf_counter()
    # skirt parts hang from the hips: they may only use torso triangles that
    # the legs do not move (no leg skin weight), so spreading the legs
    # neither tears nor swings them; the push-out pass then keeps the legs inside
    hips = (tri_labels == R.TORSO) & (leg_share[body.faces].max(axis=1) < 0.02)
    mask_labels = np.where(hips & np.isin(R.HIPS, labels), R.HIPS, tri_labels)
    mask_labels = np.where(degenerate, -1, mask_labels)
    allowed = np.zeros((len(pts), R.N_REGIONS + 1), dtype=bool)
    allowed[np.arange(len(pts)), np.where(labels == R.HIPS, R.HIPS, labels)] = True
    allowed[:, R.HIPS] |= labels == R.TORSO  # torso vertices may still use hip triangles
    binding = bind(body.points, body.faces, pts, k=k, candidate_mask=(mask_labels, allowed))
    region_labels = labels.copy()  # with the HIPS marker of skirt parts
    labels = np.where(labels == R.HIPS, R.TORSO, labels)
    t2 = time.perf_counter()
    # clearance to keep = true signed distance to the reference body (the
    # offset along a bound triangle's plane extrapolates: on a bent foot a
    # rigid shoe's plane offsets reach tens of centimetres)
    ref_query = SurfaceQuery(body.faces, body.points)
    foot = ref_query.closest(pts)
    if ref_clearance is None:
        ref_clear = foot["distance"]
    else:
        if len(ref_clearance) != len(pts):
            raise ValueError(f"ref_clearance has {len(ref_clearance)} entries for {len(pts)} item vertices")
        ref_clear = np.asarray(ref_clearance, dtype=np.float64)
    far_mask = ref_clear > far
    if far_mask.any():
        names = [m.name for m, a, b in zip(items, offsets[:-1], offsets[1:]) if far_mask[a:b].any()]
        msg = (f"{int(far_mask.sum())} item vertices are more than {far} m from the body "
               f"(items: {', '.join(names)}): they are carried along rigidly with distant body parts")
        if strict_far:
            raise GeometryError(ref.source, msg)
        warn(f"{ref.source}: {msg}")

    rigid_groups, rigid_items = [], []
    blocks = []
    for i, (item, a, b) in enumerate(zip(items, offsets[:-1], offsets[1:])):
        blocks.append(adjacency(item.faces, item.n_points))
        if rigid == "none" or rigid is None:
            continue
        comp = connected_components(blocks[-1], directed=False)[1]
        lab = labels[a:b]
        if rigid == "auto":
            groups = _auto_rigid(item, ref_clear[a:b], lab, comp, rigid_max_size,
                                 rigid_min_clearance, rigid_max_vertices)
        elif item.name in rigid:
            groups = [np.flatnonzero(lab == r) for r in np.unique(lab)]
        else:
            groups = []
        for v in groups:
            gv = v + a
            # the bound patch: body vertices of the triangles these vertices use,
            # weighted by how much they are used
            tri_w = binding.weights[gv]
            corner = body.faces[binding.triangles[gv]]  # (P, k, 3)
            bw = np.bincount(corner.ravel(), weights=np.repeat(tri_w.ravel(), 3),
                             minlength=body.n_points)
            bv = np.flatnonzero(bw > 0)
            rigid_groups.append((gv, bv, bw[bv]))
        if groups:
            rigid_items.append(item.name)
    neighbours = sp.block_diag(blocks, format="csr")
    item_faces = np.concatenate([m.faces + a for m, a in zip(items, offsets[:-1])]).astype(np.int64)
    skirt_mask = np.zeros(len(pts), dtype=bool)
    for item, a, b in zip(items, offsets[:-1], offsets[1:]):
        if item.name in skirts:
            skirt_mask[a:b] = True
    loose = looseness(ref_clear, skirt_mask)
    for gv, _, _ in rigid_groups:
        loose[gv] = 0.0  # rigid parts move as a whole already
    t3 = time.perf_counter()
    return DressPlan(items=items, binding=binding, offsets=offsets, ref_points=pts,
                     ref_clearance=ref_clear, labels=labels, tri_labels=tri_labels,
                     body_labels=body_labels, rigid_groups=rigid_groups,
                     insets_kept=_group_mask(rigid_groups, len(pts)),
                     rigid_items=rigid_items, skirt_items=skirts, neighbours=neighbours,
                     looseness=loose, smoother=LooseSmoother(neighbours, loose),
                     bind_labels=region_labels,
                     layers=layer_gaps(ref_query, pts, offsets,
                                       [(i, j, g) for i, j, g in layer_order(items, offsets, pts, ref_clear)
                                        if items[i].name not in rigid_items],  # rigid parts move as a whole
                                       ref_clear, foot=foot["point"]),
                     ref_body=body.points, item_faces=item_faces, item_edges=edges(item_faces),
                     ref_foot=(foot["triangle"], foot["bary"]), body_query=ref_query,
                     timings={"regions_s": t1 - t0, "bind_s": t2 - t1, "plan_rest_s": t3 - t2})


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
