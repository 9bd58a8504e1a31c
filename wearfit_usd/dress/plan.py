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

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from . import regions as R
from .binding import Binding, bind, rebind
from .corrections import LooseSmoother, looseness
from .layers import layer_gaps, layer_order
from .rigid_parts import RigidParts
from ..errors import GeometryError, InputError
from ..geometry.closest import SurfaceQuery
from ..geometry.mesh import adjacency, components, edges
from ..model import Character, Mesh
from ..progress import warn

FAR_FROM_BODY = 0.5  # m: items farther than this from the body are suspicious


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
