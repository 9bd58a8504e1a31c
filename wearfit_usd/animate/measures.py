"""Motion measures: how far animated items keep the shape, contact and
coverage of the same items dressed statically on the same target (plain
numpy; used by ``animate`` with ``measure_every``, ``wearfit animate
--report/--strict`` and the motion benchmark).

Built once from the static dress (:class:`MotionMeasures`: the target body
at the pose the items were dressed on, the dressed items, their rigid
groups), then called per frame with the body and item points of that
frame. Per item and per frame:

- **stretch** (``stretch_p99``, ``stretch_max``): each item edge's length
  over its length in the static dress, divided by the largest stretch the
  body itself allows under it between the static body and this frame's
  (:func:`dress.body_stretch.stretch_range`, the range the dressing measure
  judges edges by; its ``hi`` end). Values <= 1 count as 1: 1.0 means the
  edge stretched no more than the skin under it. Only lengthening is
  measured (tearing, points pulled out); compression is folding.
- **separation** (``separation_p95_mm``, ``separation_max_mm``): the change
  of each vertex's signed distance to the body against the static dress,
  over the item's *contact* vertices (within ``contact`` of the body, or
  inside it, in the static dress): a collar leaving the ankle. A skirt's hem
  hanging away from the legs is not a contact and may swing: nor are the
  *hanging* vertices (``hanging``: the loose parts the cloth simulates,
  :func:`animate.loose.cloth_weights` >= 1/2), which lie on the thighs in
  the static dress and swing off them with every step. None for items
  with fewer than 3 contact vertices (they do not touch the body).
- **coverage loss** (``coverage_loss_pct``): of the body vertices the item
  covers in the static dress (a ray from the vertex along its normal meets
  the item between ``-inset`` and ``reach`` metres), the percentage it no
  longer covers in this frame (tears, the body poking through, the item
  sliding off). None for items that cover no body vertex. On a low-poly
  body (median edge over ``COARSE_EDGE``) the vertices are too few to say
  it (Khronos' RiggedFigure: 370, a hat covering 2 of them): points spread
  over its triangles at most ``PROBE_SPACING`` apart (their rays along the
  face normal) are probes beside the vertices (:func:`coverage_probes`). Where the static
  hit is on a hanging part, the ray in the frame reaches ``hanging_reach``
  (50 cm): a skirt swinging 10 cm off the back leg still covers it (the
  skin is not seen from outside along its normal), a leg through the skirt
  or a tear does not. A body vertex *in a fold* is not counted as lost
  (``coverage_folded_pct`` reports them): its ray in this frame leaves
  another part of the body (the vertex lies inside it, however deep: the
  ray is followed to the body's bounding box) or meets the body itself no
  farther than the static hit plus ``fold_margin``. The body then
  holds the place the item held (an arm down against the torso, the thighs
  together): the vertex cannot be seen, and no item can lie there without
  entering the body.
- **rigid parts** (``rigid_mm``): the largest distance of a vertex of a rigid
  group (each articulated piece: :func:`dress.item_weights.rigid_pieces`
  splits the plan's rigid groups, a shoe per foot, into the pieces its
  skinning moves rigidly, sole, toe cap and collar, leaving out the hinges
  between them) from the best similarity transform
  (:func:`geometry.mesh.similarity_fit`) of the group's static points onto
  its points in this frame. None for items without rigid groups.
- **new penetrations** (``new_pen_pct``): item vertices outside the body in
  the static dress (clearance > 0, as the dressing's measure,
  :func:`dress.metrics.clearance_change`, counts them) and inside it by
  more than ``margin`` now, percent of the former. A vertex over a fold is not counted
  (``pen_folded_pct`` reports them): its static foot point on the body (the
  closest point, carried by its triangle into this frame) is in a fold as
  above, its ray meeting the body within the vertex's static clearance plus
  ``fold_margin``: the item is pinched between two parts of the body and
  lies inside one of them whatever it does.
- **through another item** (``through_pct``): of the item's vertices that lie
  under another item in the static dress (a vertex of another item within
  ``layer_reach`` that is at least ``layer_gap`` farther from the skin), the
  percent now farther from the skin than that vertex (by more than
  ``margin``): a top's hem coming through a skirt, layers swapping. None for
  items under no other item. Reported, not limited (issue 17 names no limit).

:class:`MotionLimits` holds the limits of issue 17 in one place.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..dress.body_stretch import local_triangles, stretch_range, vertex_stretch
from ..errors import WearfitError
from ..geometry.closest import SurfaceQuery, VertexNormals, point_and_normal
from ..geometry.mesh import edge_length_percentile, edges, similarity_fit
from ..geometry.rays import box_exit, cast_rays, centroid_reach, march_rays, ray_triangle

#: m: a body whose median edge is longer than this is low-poly: its coverage
#: is probed over its triangles too (MakeHuman bodies 6-7 mm, a remeshed
#: one 10 mm, GDQuest's mannequin 14 mm, Khronos' RiggedFigure 108 mm)
COARSE_EDGE = 0.02
#: m: the most the coverage probes on a low-poly body's triangles are apart
PROBE_SPACING = 0.02

MEASURES = ("stretch_p99", "stretch_max", "separation_p95_mm", "separation_max_mm", "coverage_loss_pct",
            "rigid_mm", "new_pen_pct", "through_pct", "coverage_folded_pct", "pen_folded_pct")


def _leaves(tri: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(R,) bool: each ray (R, 3) meets its triangle (R, 3, 3) from behind.
    The body's triangles face out: a ray whose first hit leaves through one
    started inside."""
    return np.einsum("ij,ij->i", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), dirs) > 0


def coverage_probes(points: np.ndarray, faces: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points spread over each triangle (T, 3) of a mesh (N, 3) at most
    ``spacing`` apart along its longest edge: the interior points of a
    barycentric lattice of n = ceil(longest edge / spacing) steps (a
    triangle with n < 3 has none; its corners are the mesh's vertices).

    Returns
    -------
    (triangle (S,) int64, bary (S, 3)): each point's triangle and barycentrics.
    """
    f = np.asarray(faces, dtype=np.int64)
    p = np.asarray(points, dtype=np.float64)
    v = p[f]
    longest = np.max(np.linalg.norm(v - np.roll(v, -1, axis=1), axis=2), axis=1)
    steps = np.ceil(longest / float(spacing) - 1e-9).astype(np.int64)
    tris, barys = [np.zeros(0, dtype=np.int64)], [np.zeros((0, 3))]
    for n in np.unique(steps[steps >= 3]):   # one lattice per step count, not per triangle
        i, j = np.meshgrid(np.arange(1, n), np.arange(1, n), indexing="ij")
        ok = (i + j) <= n - 1
        lat = np.stack([i[ok], j[ok], n - i[ok] - j[ok]], axis=1) / float(n)
        t = np.flatnonzero(steps == n)
        tris.append(np.repeat(t, len(lat)))
        barys.append(np.tile(lat, (len(t), 1)))
    return np.concatenate(tris), np.concatenate(barys)


@dataclass(frozen=True)
class MotionLimits:
    """Upper limits of the worst frame of each motion measure (issue 17)."""
    stretch_p99: float = 1.15          # x the body's own stretch
    stretch_max: float = 1.5           # x the body's own stretch
    coverage_loss_pct: float = 2.0     # % of the statically covered body vertices (probes)
    separation_p95_mm: float = 15.0    # items that touch the body
    rigid_mm: float = 2.0              # from the best similarity
    new_pen_pct: float = 1.0           # % of the item vertices outside in the static dress

    def violations(self, worst: dict) -> list[str]:
        """Messages for every figure over its limit. worst: {item: {measure:
        {"value": float | None, "frame": int}}} (:func:`worst_frames`)."""
        out = []
        for item, figs in worst.items():
            for key, limit in asdict(self).items():
                v = figs.get(key, {}).get("value")
                if v is not None and np.isfinite(v) and v > limit:
                    out.append(f"{item}: {key} {v:.4g} > {limit:g} (frame {figs[key]['frame']})")
                elif v is not None and not np.isfinite(v):
                    out.append(f"{item}: {key} is {v} (frame {figs[key]['frame']})")
        return out


class MotionLimitError(WearfitError):
    """``animate --strict``: a motion measure is over its limit (exit code 1)."""

    def __init__(self, path, message: str):
        self.path = str(path) if path is not None else None
        self.message = message
        super().__init__(f"{self.path or '<shot>'}: {message}")


def layer_pairs(points: np.ndarray, clearance: np.ndarray, offsets: np.ndarray, reach: float = 0.02,
                gap: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """Item vertices under another item, and the vertex over each.

    Parameters
    ----------
    points : (M, 3) the items stacked; offsets : (n_items + 1,) their
        starts; clearance : (M,) each vertex's signed distance to the body.
    reach, gap : metres: a vertex is under the nearest vertex of another
        item within ``reach`` that is at least ``gap`` farther from the skin.

    Returns
    -------
    (U,) int64 the vertices under another item, (U,) int64 the vertex over each.
    """
    m = len(points)
    n_items = len(offsets) - 1
    item_of = np.repeat(np.arange(n_items), np.diff(offsets))
    if n_items < 2 or m == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    k = int(min(12, m))
    d, idx = cKDTree(points).query(points, k=k, distance_upper_bound=reach)
    d, idx = np.asarray(d).reshape(m, k), np.asarray(idx).reshape(m, k)
    found = idx < m
    safe = np.where(found, idx, 0)
    ok = found & (item_of[safe] != item_of[:, None]) & (clearance[safe] > clearance[:, None] + gap)
    has = ok.any(axis=1)
    first = np.argmax(ok, axis=1)  # nearest first: the first qualifying neighbour
    under = np.flatnonzero(has)
    return under.astype(np.int64), safe[under, first[under]].astype(np.int64)


class BodyFrame(NamedTuple):
    """The body in one frame as the fold test casts against it: its
    triangles (T, 3, 3), a KD-tree over their centroids, their largest
    centroid-to-corner distance, the bounding box lo, hi (3,) and the
    longest ray it follows (the box's diagonal, at least the reach)."""
    tri: np.ndarray
    tree: cKDTree
    reach: float
    lo: np.ndarray
    hi: np.ndarray
    longest: float


class MotionMeasures:
    """``MotionMeasures(...)(body_f (N, 3), items_f (M, 3)) -> [dict per item]``:
    the motion measures of one frame against the static dress (see the
    module docstring).

    Parameters
    ----------
    body_faces : (T, 3) int, the target body's triangles.
    body_points : (N, 3) the target body in the static dress.
    items : list of (name, points (M_i, 3), faces (F_i, 3)): the items dressed
        statically on ``body_points``; frames pass them stacked in this order.
    rigid_groups : list (one per item) of lists of vertex index arrays
        (local to the item), or None.
    reach, inset : coverage ray segment, metres along the body normal
        (default 8 cm out, 5 mm in: items sitting just under the skin).
    contact : metres: item vertices this close to the body (or inside) in
        the static dress are the ones whose separation is measured.
    margin : metres, the inside test of the new penetrations.
    k : body triangles per item vertex for its local body stretch (the
        closest one and the ones with the nearest centroids).
    hanging : (M,) bool over the stacked items, the vertices of loose parts
        that hang free (see the module docstring), or None (none).
    hanging_reach : metres, the coverage ray's reach in a frame where the
        static hit is on a hanging part.
    layer_reach, layer_gap : metres: an item vertex is under a vertex of
        another item this near it and at least this much farther from the
        skin in the static dress (``through_pct``).
    fold_margin : metres beyond the static hit (coverage) or clearance
        (penetrations) within which the body meeting itself is a fold.
    """

    def __init__(self, body_faces: np.ndarray, body_points: np.ndarray, items: list,
                 rigid_groups: list | None = None, reach: float = 0.08, inset: float = 0.005,
                 contact: float = 0.01, margin: float = 0.001, k: int = 5, hanging: np.ndarray | None = None,
                 hanging_reach: float = 0.5, layer_reach: float = 0.02, layer_gap: float = 0.002,
                 fold_margin: float = 0.005):
        self.faces = np.ascontiguousarray(body_faces, dtype=np.int64)
        self.body0 = np.ascontiguousarray(body_points, dtype=np.float64)
        self.names = [n for n, _, _ in items]
        self.item_faces = [np.asarray(f, dtype=np.int64) for _, _, f in items]
        sizes = [len(p) for _, p, _ in items]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        self.items0 = np.concatenate([np.asarray(p, dtype=np.float64) for _, p, _ in items])
        self.reach, self.inset, self.contact, self.margin = float(reach), float(inset), float(contact), float(margin)
        self.rigid_groups = [[np.asarray(g, dtype=np.int64) for g in (gs or []) if len(g) >= 3]
                             for gs in (rigid_groups or [[] for _ in items])]
        self.query = SurfaceQuery(self.faces, self.body0)
        self.normals = VertexNormals(self.faces, len(self.body0))
        foot = self.query.closest(self.items0)
        self.clearance0 = foot["distance"]
        self.foot_tri, self.foot_bary = foot["triangle"], foot["bary"]
        # the body triangles each item vertex's local stretch is taken over
        self.triangles = local_triangles(self.body0, self.faces, self.items0, self.foot_tri, k)
        # item edges, stacked (global vertex indices), and their item
        e = [edges(f) + a for f, a in zip(self.item_faces, self.offsets[:-1])]
        self.edge_item = np.repeat(np.arange(len(items)), [len(x) for x in e])
        self.edges = np.concatenate(e) if e else np.zeros((0, 2), dtype=np.int64)
        self.len0 = np.linalg.norm(self.items0[self.edges[:, 1]] - self.items0[self.edges[:, 0]], axis=1)
        self.hanging = (np.zeros(len(self.items0), dtype=bool) if hanging is None
                        else np.asarray(hanging, dtype=bool).reshape(len(self.items0)))
        self.hanging_reach = float(hanging_reach)
        self.fold_margin = float(fold_margin)
        self.contact_mask = (self.clearance0 < self.contact) & ~self.hanging
        self.outside0 = self.clearance0 > 0.0
        self.under, self.over = layer_pairs(self.items0, self.clearance0, self.offsets, float(layer_reach),
                                            float(layer_gap))
        # coverage: the body vertices (and on a low-poly body the probes over
        # its triangles) each item covers statically, and the hit triangle
        n0 = self.normals(self.body0)
        coarse = edge_length_percentile(self.body0, self.faces, 50.0) > COARSE_EDGE
        self.probe_tri, self.probe_bary = (coverage_probes(self.body0, self.faces, PROBE_SPACING) if coarse else
                                           (np.zeros(0, dtype=np.int64), np.zeros((0, 3))))
        all_probes = np.arange(len(self.body0) + len(self.probe_tri))
        o0, d0 = self.probes(all_probes, self.body0, n0)
        # per item: the triangles sharing a vertex with each triangle (CSR rows)
        self.rings = []
        for f, n in zip(self.item_faces, sizes):
            inc = sp.csr_matrix((np.ones(3 * len(f)), (np.repeat(np.arange(len(f)), 3), f.ravel())),
                                shape=(len(f), n))
            ring = (inc @ inc.T).tocsr()
            ring.sort_indices()
            self.rings.append(ring)
        self.covered, self.cover_tri, self.cover_t = [], [], []
        for i in range(len(items)):
            sl = self._slice(i)
            hit = cast_rays(o0, d0, self.items0[sl], self.item_faces[i], -self.inset, self.reach)
            v = np.flatnonzero(hit >= 0)
            self.covered.append(v)
            self.cover_tri.append(hit[v])
            tri = self.items0[sl][self.item_faces[i][hit[v]]]
            self.cover_t.append(ray_triangle(o0[v], d0[v], tri[:, 0], tri[:, 1], tri[:, 2],
                                             -self.inset, self.reach)[1])
        # per item: the frame's reach of each covered body vertex's ray
        self.cover_reach = [np.where(self.hanging[self._slice(i)][self.item_faces[i][t]].any(axis=1),
                                     max(self.hanging_reach, self.reach), self.reach)
                            for i, t in enumerate(self.cover_tri)]

    def probes(self, idx: np.ndarray, body_points: np.ndarray, body_normals: np.ndarray):
        """Origins and unit directions (len(idx), 3) of the coverage probes
        ``idx`` on a body (N, 3) with unit vertex normals (N, 3): probe
        v < N is body vertex v along its normal, probe N + s the point s of
        :attr:`probe_tri`/:attr:`probe_bary` along its triangle's normal."""
        idx = np.asarray(idx, dtype=np.int64)
        n = len(body_points)
        o = np.empty((len(idx), 3))
        d = np.empty((len(idx), 3))
        vert = idx < n
        o[vert], d[vert] = body_points[idx[vert]], body_normals[idx[vert]]
        s = idx[~vert] - n
        if len(s):
            tri = body_points[self.faces[self.probe_tri[s]]]
            o[~vert] = np.einsum("sc,sci->si", self.probe_bary[s], tri)
            fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            d[~vert] = fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        return o, d

    def body_frame(self, body_points: np.ndarray) -> BodyFrame:
        """The fold test's view of the body (N, 3) in one frame
        (:class:`BodyFrame`), built once per frame and passed to its tests."""
        q = self.query if self.query.points is body_points else self.query.moved_to(body_points)
        tri = body_points[self.faces]
        lo, hi = body_points.min(axis=0), body_points.max(axis=0)
        return BodyFrame(tri, q.centroid_tree, float(centroid_reach(tri)[1].max()), lo, hi,
                         max(float(np.linalg.norm(hi - lo)), self.reach))

    def _folded(self, frame: BodyFrame, origins: np.ndarray, dirs: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """(P,) bool: the ray from each origin (on the body) along its unit
        dir (P, 3) leaves the body first (the origin lies inside another
        part of it) or enters it within ``depth`` (P,) metres: a fold."""
        out = np.zeros(len(origins), dtype=bool)
        if len(origins) == 0:
            return out
        eps = 1e-3  # off the origin's own triangles
        # followed on to where it leaves the body's bounding box: a ray may
        # start deep inside another part (a shoulder the skinning sinks into
        # the torso as the arm comes down leaves it 8-35 cm away:
        # ref_female_longskirt's top on body_female_heavy, CMU walk); a zero
        # direction, from a degenerate triangle, never leaves: capped at the
        # box's diagonal
        ends = np.clip(box_exit(origins, dirs, frame.lo, frame.hi), self.reach, frame.longest)
        hit, t = march_rays(origins, dirs, frame.tri, frame.tree, eps, ends, reach=frame.reach)
        ok = np.flatnonzero(hit >= 0)
        out[ok] = _leaves(frame.tri[hit[ok]], dirs[ok]) | (t[ok] <= depth[ok])
        return out

    def _slice(self, i: int) -> slice:
        return slice(int(self.offsets[i]), int(self.offsets[i + 1]))

    def coverage_loss(self, i: int, body_points: np.ndarray, body_normals: np.ndarray,
                      item_points: np.ndarray, folds: bool = True, frame: BodyFrame | None = None):
        """Percent of item i's statically covered body vertices (probes on a
        low-poly body) not covered now; body_points/body_normals (N, 3)
        (unit vertex normals), item_points (M_i, 3) this item's points.
        None if it covers nothing. With ``folds`` (the default) returns
        (loss, folded): the probes in a fold (see the module docstring) are
        counted in ``folded``, not lost; ``frame``: :meth:`body_frame` of
        body_points if already built."""
        v = self.covered[i]
        if len(v) == 0:
            return (None, None) if folds else None
        f = self.item_faces[i]
        o, d = self.probes(v, body_points, body_normals)
        reach = self.cover_reach[i]
        tri = item_points[f[self.cover_tri[i]]]
        # the static hit triangle first (it follows the item), then the
        # triangles around it, a full search for the rest
        hit, t = ray_triangle(o, d, tri[:, 0], tri[:, 1], tri[:, 2], -self.inset, float(reach.max()))
        hit &= t <= reach
        miss = np.flatnonzero(~hit)
        if len(miss):
            ring = self.rings[i]
            start = ring.indptr[self.cover_tri[i][miss]]
            lens = ring.indptr[self.cover_tri[i][miss] + 1] - start
            ray = np.repeat(miss, lens)
            first = np.repeat(np.cumsum(lens) - lens, lens)
            cand = ring.indices[np.repeat(start, lens) + np.arange(int(lens.sum())) - first]
            tc = item_points[f[cand]]
            h, t = ray_triangle(o[ray], d[ray], tc[:, 0], tc[:, 1], tc[:, 2], -self.inset, float(reach.max()))
            h &= t <= reach[ray]
            hit[ray[h]] = True
            miss = np.flatnonzero(~hit)
        if len(miss):
            # one search out to the longest reach: the nearest hit (smallest
            # |t|) lies within a ray's own reach whenever any hit does
            r = float(reach[miss].max())
            again = cast_rays(o[miss], d[miss], item_points, f, -self.inset, r)
            m = miss[again >= 0]
            if len(m):
                tc = item_points[f[again[again >= 0]]]
                h, t = ray_triangle(o[m], d[m], tc[:, 0], tc[:, 1], tc[:, 2], -self.inset, r)
                hit[m] = h & (t <= reach[m])
        if not folds:
            return 100.0 * float(np.sum(~hit)) / len(v)
        miss = np.flatnonzero(~hit)
        frame = self.body_frame(body_points) if frame is None else frame
        fold = self._folded(frame, o[miss], d[miss], np.maximum(self.cover_t[i][miss], 0.0) + self.fold_margin)
        return 100.0 * float(np.sum(~fold)) / len(v), 100.0 * float(np.sum(fold)) / len(v)

    def __call__(self, body_points: np.ndarray, item_points: np.ndarray) -> list[dict]:
        """Per-item figures of one frame: body_points (N, 3) and the items
        stacked (M, 3), both in the static dress's space. Returns one dict
        per item with the keys of :data:`MEASURES` (None where a measure
        does not apply)."""
        body = np.ascontiguousarray(body_points, dtype=np.float64)
        pts = np.ascontiguousarray(item_points, dtype=np.float64)
        # stretch against the body's own under each edge
        vr = vertex_stretch(self.triangles, self.body0, body, self.faces)
        _, hi = stretch_range(self.items0, self.edges, self.triangles, self.body0, body, self.faces,
                              self.foot_tri, self.foot_bary, self.clearance0, vertex_range=vr)
        ln = np.linalg.norm(pts[self.edges[:, 1]] - pts[self.edges[:, 0]], axis=1)
        beyond = np.maximum(ln / np.maximum(self.len0, 1e-12) / np.maximum(hi, 1e-12), 1.0)
        # signed distance now
        self.query.update(body)
        dist = self.query.signed_distance(pts)
        normals = self.normals(body)
        frame = self.body_frame(body)  # the fold tests' (after the update: its tree is the query's)
        rows = []
        for i, name in enumerate(self.names):
            sl = self._slice(i)
            b = beyond[self.edge_item == i]
            row = {"item": name,
                   "stretch_p99": float(np.percentile(b, 99)) if len(b) else 1.0,
                   "stretch_max": float(b.max()) if len(b) else 1.0}
            c = self.contact_mask[sl]
            if c.sum() >= 3:
                sep = 1000.0 * np.abs(dist[sl][c] - self.clearance0[sl][c])
                row["separation_p95_mm"] = float(np.percentile(sep, 95))
                row["separation_max_mm"] = float(sep.max())
            else:
                row["separation_p95_mm"] = row["separation_max_mm"] = None
            row["coverage_loss_pct"], row["coverage_folded_pct"] = self.coverage_loss(
                i, body, normals, pts[sl], frame=frame)
            groups = self.rigid_groups[i]
            if groups:
                p0, p1 = self.items0[sl], pts[sl]
                res = 0.0
                for g in groups:
                    s, rot, t = similarity_fit(p0[g], p1[g])
                    res = max(res, float(np.linalg.norm(s * p0[g] @ rot + t - p1[g], axis=1).max()))
                row["rigid_mm"] = 1000.0 * res
            else:
                row["rigid_mm"] = None
            out0 = self.outside0[sl]
            new = np.flatnonzero(out0 & (dist[sl] < -self.margin)) + sl.start
            # over a fold: the static foot point, carried by its triangle, and its normal
            foot, fn = point_and_normal(body, normals, self.faces, self.foot_tri[new], self.foot_bary[new])
            fold = self._folded(frame, foot, fn, np.maximum(self.clearance0[new], 0.0) + self.fold_margin)
            n_out = int(out0.sum())
            row["new_pen_pct"] = 100.0 * float(np.sum(~fold)) / n_out if n_out else 0.0
            row["pen_folded_pct"] = 100.0 * float(np.sum(fold)) / n_out if n_out else 0.0
            mine = (self.under >= sl.start) & (self.under < sl.stop)
            if mine.any():
                u, o = self.under[mine], self.over[mine]
                row["through_pct"] = 100.0 * float(np.mean(dist[u] > dist[o] + self.margin))
            else:
                row["through_pct"] = None
            rows.append(row)
        return rows


def worst_frames(series: dict, frames: list) -> dict:
    """The worst frame of every measure per item.

    series: {item: {measure: [value per measured frame]}} (None entries
    where the measure does not apply), frames: the measured frame numbers.
    Returns {item: {measure: {"value": float | None, "frame": int | None}}}:
    the largest value (NaN counts as worst) and its frame."""
    out = {}
    for item, figs in series.items():
        out[item] = {}
        for key in MEASURES:
            vals = figs.get(key, [])
            best, at = None, None
            for v, f in zip(vals, frames):
                if v is None:
                    continue
                if best is None or not np.isfinite(v) or (np.isfinite(best) and v > best):
                    best, at = float(v), int(f)
                    if not np.isfinite(v):
                        break
            out[item][key] = {"value": best, "frame": at}
    return out


def describe_worst(item: str, figs: dict, limits: MotionLimits | None = None) -> str:
    """One line: the worst frame of each measure of one item, ``!`` after a
    figure over its limit. figs: one item of :func:`worst_frames`."""
    lim = asdict(limits or MotionLimits())

    def fig(key, fmt, unit):
        w = figs.get(key, {})
        v = w.get("value")
        if v is None:
            return "-"
        flag = "!" if key in lim and not (v <= lim[key]) else ""
        return f"{v:{fmt}}{unit}{flag} (f{w.get('frame')})"
    return (f"{item}: stretch p99 {fig('stretch_p99', '.3g', 'x')} max {fig('stretch_max', '.3g', 'x')}; "
            f"separation p95 {fig('separation_p95_mm', '.3g', ' mm')} max {fig('separation_max_mm', '.3g', ' mm')}; "
            f"coverage loss {fig('coverage_loss_pct', '.3g', ' %')}; rigid {fig('rigid_mm', '.3g', ' mm')}; "
            f"new penetrations {fig('new_pen_pct', '.3g', ' %')}; "
            f"through another item {fig('through_pct', '.3g', ' %')}")
