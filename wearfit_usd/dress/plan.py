"""The dressing plan: everything topology-dependent about a reference's items,
built once on the reference body (:func:`plan`, :class:`DressPlan`).

1. segment the reference body by skin weights (:mod:`regions`) and give each
   item vertex the region of its nearest body triangle; item parts that join
   the two legs directly (skirts, dresses) are bound to the torso instead, so
   no vertex is pulled by both legs and the skirt cannot tear between them
   (:func:`item_labels`);
2. bind every item vertex to its ``k`` nearest reference triangles of its
   region (:func:`binding.bind`, one sparse matrix for all items);
3. find the small stiff parts (shoes, hat, glasses, watch) that follow a
   best-fit similarity transform of their bound body patch instead, the
   loose parts whose displacement is smoothed (:mod:`corrections`) and the
   layer order between items (:mod:`layers`).

:mod:`apply` evaluates a plan on a fitted body.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import GeometryError, InputError
from ..geometry.closest import SurfaceQuery
from ..geometry.mesh import adjacency, components, edges, nondegenerate
from ..model import Character, Mesh
from ..progress import warn
from . import regions as R
from .binding import Binding, bind, blend_rows, rebind
from .bridges import bridge_weights, item_joint_weights
from .corrections import LooseSmoother, looseness
from .layers import layer_gaps, layer_order, under_skirts
from .rigid_parts import RigidParts
from .seams import SEAM_BAND, seam_shares
from .surface_layers import surface_gaps

SKIRT_K = 60  # hip triangles each skirt-part vertex is bound to (see bind_items)
SKIRT_TOP = 0.18  # m above the crotch: the parts of a skirt-like item above this (a bodice, a jacket) bind to the
                  # torso (animate.loose's attachment band ends at the same height)
TOP_ABOVE = 0.15  # m above that an item must reach to have a top (a bodice, a jacket), not just a waistband
FAR_FROM_BODY = 0.5  # m: items farther than this from the body are suspicious
DEGENERATE_BODY_REL = 1e-10  # body triangles below this x the median doubled area are not bound to


def group_mask(groups: list, m: int) -> np.ndarray:
    """The vertices of rigid groups.

    Parameters
    ----------
    groups : list
        [(vertex indices, ...)].
    m : int
        Number of vertices.

    Returns
    -------
    (m,) bool array
    """
    mask = np.zeros(m, dtype=bool)
    for gv, *_ in groups:
        mask[gv] = True
    return mask


#: an item with at least this share of its vertices in rigid groups is a
#: rigid item (shoes, a hat, glasses, stiff shorts: 1.0 on the dev references;
#: the long skirt's top has a rigid group over 9 % of it: it stays bound)
RIGID_ITEM_SHARE = 0.9
#: metres: an item whose vertices lie this near the reference body (95 %) is a decal on the skin
DECAL_CLEARANCE = 0.003


@dataclass(frozen=True)
class ItemRegions:
    """Body regions (:mod:`regions`) of a plan: per item vertex, body
    triangle and body vertex, and the items treated as skirts."""
    vertex: np.ndarray      # (M,) region each item vertex is bound to (skirt parts: TORSO)
    bind: np.ndarray        # (M,) the regions used for binding (skirt parts: HIPS); pass to plan(regions=...)
    triangle: np.ndarray    # (T,) region of each body triangle
    body: np.ndarray        # (N,) region of each body vertex
    skirt_items: list       # names of the items bound as skirts (from the hips)


@dataclass(frozen=True)
class StackedMesh:
    """The items' meshes stacked into one (vertex indices into the stacked points)."""
    faces: np.ndarray            # (F, 3) triangles of all items
    edges: np.ndarray            # (E, 2) their unique edges
    neighbours: sp.csr_matrix    # (M, M) vertex adjacency (block diagonal, one block per item)


class Footprint(NamedTuple):
    """The closest reference skin point of each item vertex."""
    triangle: np.ndarray    # (M,) body triangle
    bary: np.ndarray        # (M, 3) barycentrics in it


@dataclass(frozen=True)
class AutoRigid:
    """Which item parts :func:`plan` moves rigidly with ``rigid="auto"``:
    small (bounding-box diagonal <= max_size m), not skin-tight (median
    clearance >= min_clearance m) parts of at most max_vertices vertices
    lying in one body region."""
    max_size: float = 0.4
    min_clearance: float = 0.004
    max_vertices: int = 4000


def mostly_rigid(offsets: np.ndarray, rigid_rows: np.ndarray) -> list:
    """Indices of the items most of whose vertices (``rigid_rows`` (M,)
    bool; ``offsets`` their stacked ranges) are in rigid groups: shoes, a
    hat, short hair, not a suit with a rigid belt."""
    return [k for k, (a, b) in enumerate(zip(offsets[:-1], offsets[1:])) if b > a and rigid_rows[a:b].mean() > 0.5]


@dataclass
class DressPlan:
    """Everything topology-dependent, built once on the reference body.

    items: the reference items, their vertices stacked in item order (M in all);
    binding: one :class:`Binding` for all item vertices;
    offsets: (n_items + 1,) start of each item's rows;
    ref_points: (M, 3) the stacked item points on the reference;
    ref_body: (N, 3) the reference body points;
    ref_clearance: (M,) signed clearance on the reference body (m), kept on targets;
    ref_foot: the closest reference skin point of each item vertex;
    body_query: a :class:`SurfaceQuery` on the reference body (its topology serves every target);
    regions: body regions of the item vertices, body triangles and vertices;
    mesh: the items' stacked triangles, edges and adjacency;
    rigid_groups: list of (vertex indices (P,), body vertex indices (Q,),
        body vertex weights (Q,)) moved by one similarity transform;
    rigid_items: names of the items with rigid groups;
    insets_kept: (M,) bool, vertices that keep authored insets (the plan's
        rigid groups, also when :func:`repair.release_misfits` frees them);
    looseness: (M,) 0..1, how much each vertex's displacement is smoothed
        over the item mesh: 0 for tight parts (clearance kept exactly), 1 for
        parts hanging far from the body, and a band around the places where
        an item bridges a fold of the body (:mod:`bridges`);
    smoother: the :class:`LooseSmoother` of that weight;
    layers: [(outer item, inner item, separation (n_outer,) m, inner vertex
        (n_outer,))] (:func:`layers.layer_gaps`, skirts over the parts they
        enclose: :func:`layers.under_skirts`);
    timings: seconds per planning step;
    rigid_parts: the rigid groups' per-body evaluator (None without groups);
    released_groups: rigid groups (as ``rigid_groups``) that
        :func:`repair.release_misfits` freed on this target: bound freely for
        the static fit, still rigid pieces in motion
        (:func:`item_weights.skinned_items`).
    """
    items: list[Mesh]
    binding: Binding
    offsets: np.ndarray
    ref_points: np.ndarray
    ref_body: np.ndarray
    ref_clearance: np.ndarray
    ref_foot: Footprint
    body_query: SurfaceQuery = field(repr=False, compare=False)
    regions: ItemRegions
    mesh: StackedMesh
    rigid_groups: list
    rigid_items: list
    insets_kept: np.ndarray
    looseness: np.ndarray
    smoother: LooseSmoother
    layers: list
    timings: dict = field(default_factory=dict)
    released_groups: list = field(default_factory=list)  # rigid groups repair.release_misfits freed on a target
    rigid_parts: RigidParts | None = field(init=False, default=None)

    def __post_init__(self):
        if self.rigid_groups:
            self.rigid_parts = RigidParts(self.rigid_groups, self.ref_body, self.ref_points)

    def rigid_mask(self) -> np.ndarray:
        """(M,) bool: item vertices of the rigid groups."""
        return group_mask(self.rigid_groups, len(self.ref_points))

    def rigid_item_rows(self) -> list:
        """Indices of the items rigid as a whole on the reference
        (:func:`mostly_rigid`), released on this target or not."""
        return mostly_rigid(self.offsets, group_mask(list(self.rigid_groups) + list(self.released_groups),
                                                     len(self.ref_points)))

    def skin_decals(self) -> set:
        """Names of the items that lie on the skin, like a decal: 95 % of
        their vertices within :data:`DECAL_CLEARANCE` of the reference body
        (eyebrows, eyelashes, a tattoo; the tight suits' p95 is 11-35 mm).
        They follow the skin itself: an animation skins them with the weights
        of their binding (the skin under them), which no penetration pass
        lifts off it."""
        return {m.name for m, sl in zip(self.items, self.item_slices())
                if sl.stop > sl.start and np.percentile(np.abs(self.ref_clearance[sl]), 95) <= DECAL_CLEARANCE}

    def wholly_rigid(self) -> set:
        """Names of the items that are rigid as a whole: at least
        :data:`RIGID_ITEM_SHARE` of their vertices in rigid groups (shoes, a
        hat, glasses; not a top with a rigid patch)."""
        if not self.rigid_items:
            return set()
        mask = self.rigid_mask()
        return {m.name for m, sl in zip(self.items, self.item_slices())
                if m.name in self.rigid_items and mask[sl].mean() >= RIGID_ITEM_SHARE}

    def skirt_mask(self, parts: bool = False) -> np.ndarray:
        """(M,) bool: the rows of the items bound as skirts
        (``regions.skirt_items``); with ``parts`` only their skirt parts
        (bound to the hips). All False without regions."""
        if self.regions is None:
            return np.zeros(len(self.ref_points), dtype=bool)
        return skirt_rows(self.items, self.offsets, self.regions.skirt_items, self.regions.bind if parts else None)

    def item_slices(self) -> list[slice]:
        """The rows of each item in the stacked arrays.

        Returns
        -------
        list of slice
        """
        return [slice(int(a), int(b)) for a, b in zip(self.offsets[:-1], self.offsets[1:])]

    def rebound(self, body_points: np.ndarray, item_points: np.ndarray) -> DressPlan:
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
    parts (item edges joining a left-leg vertex to a right-leg vertex; below
    ``SKIRT_TOP`` above the crotch) moved to the hips (HIPS). Returns
    (labels (M,), names of items treated as skirts)."""
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
        # the skirt part only: a dress's bodice or a suit's jacket above the
        # hips is bound to the torso like any top (bound to the hips, with
        # SKIRT_K triangles and smoothed as a skirt, its shoulders stayed
        # behind when the arms went up)
        # (a skirt alone, its waistband included, stays on the hips)
        top = np.zeros(comp.max() + 1)
        np.maximum.at(top, comp, points[a:b, 1])
        has_top = top[comp] > crotch_y + SKIRT_TOP + TOP_ABOVE
        low = ~has_top | (points[a:b, 1] < crotch_y + SKIRT_TOP)
        legs = (lab == R.LEFT_LEG) | (lab == R.RIGHT_LEG)
        sel = np.isin(comp, bridged) & low & (legs | (lab == R.TORSO))
        lab[sel] = R.HIPS
        lab[np.isin(comp, bridged) & ~low & legs] = R.TORSO  # the sides of the hips above it
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


def stack_items(ref: Character):
    """The items of ``ref`` stacked in item order.

    Parameters
    ----------
    ref : Character

    Returns
    -------
    items : list of Mesh
    offsets : (n_items + 1,) int array
        Start of each item's rows.
    points : (M, 3) float array
    """
    items = list(ref.items)
    if not items:
        raise InputError(ref.source, "the reference holds no wearable items (no Mesh besides the body)")
    offsets = np.concatenate([[0], np.cumsum([m.n_points for m in items])])
    return items, offsets, np.concatenate([m.points for m in items])


def degenerate_triangles(ref: Character) -> np.ndarray:
    """The zero-area body triangles of ``ref`` (doubled area at most
    ``DEGENERATE_BODY_REL`` x the median, :func:`geometry.mesh.nondegenerate`),
    which binding leaves out, with a warning; an error if every triangle is.

    Parameters
    ----------
    ref : Character

    Returns
    -------
    (T,) bool array
    """
    degenerate = ~nondegenerate(ref.body.points, ref.body.faces, rel=DEGENERATE_BODY_REL)
    if degenerate.all():
        raise GeometryError(ref.source, "every body triangle is degenerate (zero area)")
    if degenerate.any():
        warn(f"{ref.source}: {int(degenerate.sum())} degenerate body triangles are not used for binding")
    return degenerate


class BodyRegions(NamedTuple):
    """Regions of the reference body from its skin weights."""
    vertex: np.ndarray      # (N,) region of each body vertex (all TORSO without regions)
    triangle: np.ndarray    # (T,) region of each body triangle
    leg_share: np.ndarray   # (N,) skin weight of the two legs


def body_regions(ref: Character, use_regions: bool) -> BodyRegions:
    """The reference body segmented by skin weights (:mod:`regions`), or one
    region if ``use_regions`` is off or the body has no skin weights.

    Parameters
    ----------
    ref : Character
    use_regions : bool

    Returns
    -------
    BodyRegions
        vertex (N,), triangle (T,) regions and leg_share (N,).
    """
    body = ref.body
    if use_regions and ref.skeleton is not None and body.joint_indices is not None:
        shares = R.region_shares(body, ref.skeleton)
        body_labels = np.argmax(shares, axis=1)
        leg_share = shares[:, R.LEFT_LEG] + shares[:, R.RIGHT_LEG]
    else:
        body_labels = np.zeros(body.n_points, dtype=np.int64)
        leg_share = np.zeros(body.n_points)
    return BodyRegions(body_labels, R.triangle_regions(body.faces, body_labels), leg_share)


def bind_items(body: Mesh, points: np.ndarray, labels: np.ndarray, regions: BodyRegions,
               degenerate: np.ndarray, k: int, item_edges: np.ndarray | None = None,
               seam_band: float = SEAM_BAND) -> Binding:
    """Bind item points to the ``k`` nearest non-degenerate body triangles of
    their region.

    Skirt parts hang from the hips: they may only use torso triangles that the
    legs do not move (no leg skin weight), so spreading the legs neither tears
    nor swings them; the push-out pass then keeps the legs inside. Torso
    vertices may still use hip triangles. Skirt parts use ``SKIRT_K`` hip
    triangles each: a hem hangs tens of centimetres below the hips, tens of
    times the size of a hip triangle, and each triangle's frame extrapolates
    that far; with a few triangles each, neighbouring hem vertices followed
    different small patches (the left and right buttock) and a thinner body
    split the skirt open at the back and pulled its hem into points. Blended
    over a wide patch, the hem follows the hips' overall shape.

    Across the line where an item passes from one region to another (a
    sleeve sewn to a jacket, a collar, trousers at the waist) the vertices
    within ``seam_band`` along the item follow both regions, blended
    (:mod:`seams`): bound to one region each, the two sides of the line
    tore apart when the limb moved.

    Parameters
    ----------
    body : Mesh
        The reference body.
    points : (M, 3) float array
    labels : (M,) int array
        Region of each item vertex (skirt parts: HIPS).
    regions : BodyRegions
    degenerate : (T,) bool array
    k : int
    item_edges : (E, 2) int array, optional
        The items' edges (stacked indices); without them nothing is blended.
    seam_band : float
        m along the item (0: no blending).

    Returns
    -------
    Binding
    """
    tri_labels = regions.triangle
    hips = (tri_labels == R.TORSO) & (regions.leg_share[body.faces].max(axis=1) < 0.02)
    mask_labels = np.where(hips & np.isin(R.HIPS, labels), R.HIPS, tri_labels)
    mask_labels = np.where(degenerate, -1, mask_labels)
    allowed = np.zeros((len(points), R.N_REGIONS + 1), dtype=bool)
    allowed[np.arange(len(points)), np.where(labels == R.HIPS, R.HIPS, labels)] = True
    allowed[:, R.HIPS] |= labels == R.TORSO
    k_rows = np.where(labels == R.HIPS, max(int(k), SKIRT_K), int(k))
    binding = bind(body.points, body.faces, points, k=k_rows, candidate_mask=(mask_labels, allowed))
    if item_edges is None or seam_band <= 0:
        return binding
    other, share = seam_shares(points, item_edges, labels, seam_band)
    rows = np.flatnonzero(other >= 0)
    if len(rows) == 0:
        return binding
    lab2 = other[rows]
    allowed2 = np.zeros((len(rows), R.N_REGIONS + 1), dtype=bool)
    allowed2[np.arange(len(rows)), lab2] = True
    allowed2[:, R.HIPS] |= lab2 == R.TORSO
    second = bind(body.points, body.faces, points[rows], k=np.where(lab2 == R.HIPS, max(int(k), SKIRT_K), int(k)),
                  candidate_mask=(mask_labels, allowed2))
    return blend_rows(binding, body.points, points, rows, second, share[rows])


def reference_clearance(ref: Character, query: SurfaceQuery, items: list[Mesh], offsets: np.ndarray,
                        points: np.ndarray, given: np.ndarray | None, far: float, strict_far: bool):
    """The clearance each item vertex keeps: the true signed distance of the item
    points to the reference body (the offset along a bound triangle's plane
    extrapolates: on a bent foot a rigid shoe's plane offsets reach tens of
    centimetres), or the ``given`` one. Items farther than ``far`` from the
    body are warned about (an error with ``strict_far``).

    Parameters
    ----------
    ref : Character
    query : SurfaceQuery
        On the reference body.
    items : list of Mesh
    offsets : (n_items + 1,) int array
    points : (M, 3) float array
    given : (M,) float array or None
    far : float
        m.
    strict_far : bool

    Returns
    -------
    clearance : (M,) float array
    foot : dict
        :meth:`SurfaceQuery.closest` of ``points``.
    """
    foot = query.closest(points)
    if given is None:
        clearance = foot["distance"]
    else:
        if len(given) != len(points):
            raise ValueError(f"ref_clearance has {len(given)} entries for {len(points)} item vertices")
        clearance = np.asarray(given, dtype=np.float64)
    far_mask = clearance > far
    if far_mask.any():
        names = [m.name for m, a, b in zip(items, offsets[:-1], offsets[1:]) if far_mask[a:b].any()]
        msg = (f"{int(far_mask.sum())} item vertices are more than {far} m from the body "
               f"(items: {', '.join(names)}): they are carried along rigidly with distant body parts")
        if strict_far:
            raise GeometryError(ref.source, msg)
        warn(f"{ref.source}: {msg}")
    return clearance, foot


def stacked_mesh(items: list[Mesh], offsets: np.ndarray) -> StackedMesh:
    """The items' triangles, edges and adjacency in stacked vertex indices.

    Parameters
    ----------
    items : list of Mesh
    offsets : (n_items + 1,) int array

    Returns
    -------
    StackedMesh
    """
    faces = np.concatenate([m.faces + a for m, a in zip(items, offsets[:-1])]).astype(np.int64)
    neighbours = sp.block_diag([adjacency(m.faces, m.n_points) for m in items], format="csr")
    return StackedMesh(faces=faces, edges=edges(faces), neighbours=neighbours)


def find_rigid_groups(items: list[Mesh], offsets: np.ndarray, labels: np.ndarray, clearance: np.ndarray,
                      binding: Binding, rigid, auto: AutoRigid):
    """The item parts moved as a whole, each with its bound body patch: the body
    vertices of the triangles its vertices use, weighted by how much they are
    used.

    Parameters
    ----------
    items : list of Mesh
    offsets : (n_items + 1,) int array
    labels : (M,) int array
        Body region of each item vertex.
    clearance : (M,) float array
    binding : Binding
    rigid : "auto", "none", None or list of str
        "auto": the small stiff parts of ``auto``; a list: those items, one
        group per body region; "none"/None: no group.
    auto : AutoRigid

    Returns
    -------
    groups : list
        [(stacked vertex indices (P,), body vertices (Q,), their weights (Q,))].
    names : list of str
        The items with groups.
    """
    groups, names = [], []
    if rigid == "none" or rigid is None:
        return groups, names
    for item, a, b in zip(items, offsets[:-1], offsets[1:]):
        lab = labels[a:b]
        if rigid == "auto":
            comp = connected_components(adjacency(item.faces, item.n_points), directed=False)[1]
            local = _auto_rigid(item, clearance[a:b], lab, comp, auto.max_size, auto.min_clearance,
                                auto.max_vertices)
        elif item.name in rigid:
            local = [np.flatnonzero(lab == r) for r in np.unique(lab)]
        else:
            local = []
        for v in local:
            gv = v + a
            groups.append((gv, *binding.body_patch(gv)))
        if local:
            names.append(item.name)
    return groups, names


def _group_items(groups: list, items: list[Mesh], offsets: np.ndarray) -> list[str]:
    """The item name of each rigid group."""
    return [items[int(np.searchsorted(offsets, gv[0], side="right") - 1)].name for gv, *_ in groups]


def skirt_rows(items: list[Mesh], offsets: np.ndarray, skirts, labels: np.ndarray | None = None) -> np.ndarray:
    """(M,) bool: the stacked rows of the items named in ``skirts``; with
    ``labels`` (binding labels, :mod:`regions`) only their skirt parts (HIPS)."""
    mask = np.zeros(int(offsets[-1]), dtype=bool)
    for item, a, b in zip(items, offsets[:-1], offsets[1:]):
        if item.name in skirts:
            mask[a:b] = True if labels is None else np.asarray(labels[a:b]) == R.HIPS
    return mask


def loose_weights(items: list[Mesh], offsets: np.ndarray, skirts: list, clearance: np.ndarray,
                  groups: list, labels: np.ndarray | None = None) -> np.ndarray:
    """How much each vertex's displacement is smoothed (:func:`corrections.looseness`):
    the skirt parts of skirt items entirely (with ``labels``: the vertices
    bound to the hips; the sleeves of a one-piece suit turn with the arms,
    and a smoothed displacement of a turning part shrinks it: raised, the
    sleeves sank into the arms), rigid parts not at all (they move as a
    whole already).

    Parameters
    ----------
    items : list of Mesh
    offsets : (n_items + 1,) int array
    skirts : list of str
    clearance : (M,) float array
    groups : list
        Rigid groups.
    labels : (M,) int array, optional
        Binding labels (:mod:`regions`; HIPS: skirt parts).

    Returns
    -------
    (M,) float array
        0..1.
    """
    loose = looseness(clearance, skirt_rows(items, offsets, skirts, labels))
    for gv, _, _ in groups:
        loose[gv] = 0.0
    return loose


def plan(ref: Character, k: int = 5, use_regions: bool = True, rigid="auto", auto_rigid: AutoRigid | None = None,
         far: float = FAR_FROM_BODY, strict_far: bool = False, regions: ItemRegions | None = None,
         ref_clearance: np.ndarray | None = None, free_items=(), seam_band: float = SEAM_BAND) -> DressPlan:
    """Bind every item of ``ref`` to its body (done once per reference).

    Parameters
    ----------
    ref : Character
        The reference: body and items (internal space).
    k : int
        Body triangles per item vertex.
    use_regions : bool
        Bind each vertex within its body region (:mod:`regions`).
    rigid : "auto", "none" or list of str
        "auto": small stiff parts (see :class:`AutoRigid`); "none"; or the
        names of items moved rigidly as a whole (per body region).
    auto_rigid : AutoRigid, optional
        The thresholds of "auto".
    far : float
        m; item vertices farther than this from the body are warned about.
    strict_far : bool
        Make that an error.
    regions : ItemRegions, optional
        The regions of an earlier plan of these items (``DressPlan.regions``),
        e.g. of the reference in its rest pose: its binding regions and skirt
        items are used. Regions are best told apart with the limbs away from
        the body: a posed body (hands hanging beside a skirt) would hand skirt
        vertices to the arms. Default: found on this body.
    ref_clearance : (M,) float array, optional
        Clearance each item vertex keeps (signed distance to the body it was
        authored on); default: measured on ``ref``. A posed reference passes
        its rest-pose clearance: posing moves rigid parts (a shoe over bending
        toes) through the skin, which is no reason to leave them there.
    free_items : sequence of str
        Items never moved rigidly (e.g. the ones a dressing released on this
        body, :func:`repair.release_misfits`: bound freely, they deform with
        the body under them; a shoe fitted to a body's bending low-poly foot
        follows that foot, where a rigid one comes off it at the toes).
    seam_band : float
        m: where an item crosses from one body region to another, the band
        along it that follows both (:func:`bind_items`); 0 binds every
        vertex within its own region only.

    Returns
    -------
    DressPlan
    """
    t0 = time.perf_counter()
    items, offsets, pts = stack_items(ref)
    body = ref.body
    degenerate = degenerate_triangles(ref)
    body_reg = body_regions(ref, use_regions)
    if regions is None:
        good = np.flatnonzero(~degenerate)
        tree = cKDTree(body.points[body.faces].mean(axis=1)[good])
        labels, skirts = item_labels(body, body_reg.vertex, body_reg.triangle[good], items, pts, offsets, tree)
    else:
        if len(regions.bind) != len(pts):
            raise ValueError(f"the given regions have {len(regions.bind)} entries for {len(pts)} item vertices")
        labels, skirts = np.asarray(regions.bind).copy(), list(regions.skirt_items)
    t1 = time.perf_counter()
    mesh = stacked_mesh(items, offsets)
    binding = bind_items(body, pts, labels, body_reg, degenerate, k, item_edges=mesh.edges,
                         seam_band=seam_band if use_regions else 0.0)
    t2 = time.perf_counter()
    ref_query = SurfaceQuery(body.faces, body.points)
    ref_clear, foot = reference_clearance(ref, ref_query, items, offsets, pts, ref_clearance, far, strict_far)
    item_regions = ItemRegions(vertex=np.where(labels == R.HIPS, R.TORSO, labels), bind=labels,
                               triangle=body_reg.triangle, body=body_reg.vertex, skirt_items=skirts)
    rigid_groups, rigid_items = find_rigid_groups(items, offsets, item_regions.vertex, ref_clear, binding,
                                                  rigid, auto_rigid or AutoRigid())
    if free_items:
        keep = [(gv, item) for gv, item in zip(rigid_groups, _group_items(rigid_groups, items, offsets))
                if item not in free_items]
        rigid_groups = [g for g, _ in keep]
        rigid_items = [n for n in rigid_items if n not in free_items]
    loose = loose_weights(items, offsets, skirts, ref_clear, rigid_groups, labels)
    rigid_rows = group_mask(rigid_groups, len(pts))
    if use_regions and ref.skeleton is not None and body.joint_indices is not None:
        # places where neighbouring item vertices follow different joints
        # (an item bridging a fold of the body) are smoothed over a band
        omega = item_joint_weights(binding.triangles, binding.weights, body.faces, body.joint_indices,
                                   body.joint_weights, ref.skeleton.n_joints)
        bridged = bridge_weights(omega, pts, mesh.edges)
        bridged[rigid_rows] = 0.0
        loose = np.maximum(loose, bridged)
    t3 = time.perf_counter()
    order = [(i, j, g) for i, j, g in layer_order(items, offsets, pts, ref_clear)
             if items[i].name not in rigid_items]  # rigid parts move as a whole
    return DressPlan(items=items, binding=binding, offsets=offsets, ref_points=pts, ref_body=body.points,
                     ref_clearance=ref_clear, ref_foot=Footprint(foot["triangle"], foot["bary"]),
                     body_query=ref_query, regions=item_regions, mesh=mesh,
                     rigid_groups=rigid_groups, rigid_items=rigid_items,
                     insets_kept=rigid_rows,
                     looseness=loose, smoother=LooseSmoother(mesh.neighbours, loose, bound=binding, points=pts),
                     layers=under_skirts(surface_gaps(layer_gaps(ref_query, pts, offsets, order, ref_clear,
                                                                 foot=foot["point"]),
                                                      offsets, mesh.faces, body.faces, body.points, pts,
                                                      movable=~rigid_rows,
                                                      rigid_inner=mostly_rigid(offsets, rigid_rows)),
                                         items, offsets, pts, ref_clear, foot["point"], skirts, fixed=rigid_rows),
                     timings={"regions_s": t1 - t0, "bind_s": t2 - t1, "plan_rest_s": t3 - t2})
