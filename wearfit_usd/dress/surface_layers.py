"""Outer layers kept over the items under them, surface against surface
(plain numpy; lengths in metres).

The dress plan orders the layers on the reference (:mod:`layers`: each
vertex of an outer item keeps a separation over one vertex of the item under
it), and :func:`layers.keep_layers` lifts outer vertices by that rule,
vertex against vertex. That rule cannot see an inner triangle standing over
the outer vertex between the inner's vertices: a coarse inner layer comes
through a fine outer one. ``ref_female_longskirt``'s skirt (vertices 42 mm
apart) stood out through the top's hem in tongues, statically on
``body_female_heavy`` (7 % of the top's vertices over the skirt lay under
it) and in every frame of the arms-held-high dance (12-24 %), where no
layer pass ran: the evaluated items follow the body each on its own.

:class:`SurfaceLayers`, both ways round, along the body normal (of each
vertex's nearest body vertex, followed over the body's edges from call to
call):

- each outer vertex of the plan's layers (those with an inner partner on
  the reference and a positive separation) looks for the inner item's
  surface among the triangles within two face rings of the inner vertex
  nearest to it now (in the inner item's parts the plan pairs it with: the
  hot pants, not the top of the same suit); the highest hit within
  ``reach`` above it, plus the separation to keep, is how far it is lifted::

      need_i = (height of the inner surface over p_i along n_i) + sep_i
      p_i   <- p_i + max(need_i, 0) n_i

- each inner vertex under those outer vertices looks for the outer item's
  triangle over it the same way; where that lies less than the separation
  over it (a fine inner layer through a coarse outer one, between the
  outer's vertices: hot pants through the skirt), the inner vertex is pulled
  in toward the skin, down to ``UNDER_MIN_CLEARANCE`` over it, and what that
  cannot take lifts the triangle's corners;

and the moves are spread over three rings of their item's mesh, a share
each ring (:func:`_spread`; a pull no deeper than each vertex's own room).
Where the plan's separation is not
positive (the reference interleaves the two there) the vertex is left to
the vertex rule, and no item rigid as a whole (shoes, a hat) is an inner
layer here. A lift is capped at ``reach + sep``: an inner surface farther
up is another sheet (a lapel, a fold), not this layer coming through.

Built once on a dress; :func:`animate.try_on.animate` runs it every frame
(the first included) between the penetration guard and the strain limit;
:func:`apply.apply` after its passes when asked (``surface_layers``; its
moves then spread over the items once more: off by default, see
:class:`apply.PassOptions`).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..geometry.closest import VertexNormals
from ..geometry.mesh import adjacency, components
from ..kernels import first_hits, vertex_incidence

#: m: how far above an outer vertex the inner surface is looked for
REACH = 0.02
#: m: the least clearance an inner vertex is pulled down to under an outer layer
UNDER_MIN_CLEARANCE = 0.001
#: the share of a push each ring of neighbours takes, and how many rings
SPREAD_DECAY = 0.6
SPREAD_RINGS = 3


def _face_rings(faces: np.ndarray, n_points: int, seeds: np.ndarray, rings: int = 2) -> np.ndarray:
    """The faces within ``rings`` face rings of each seed vertex: (S, C)
    face indices padded with -1 (C the largest count)."""
    inc = vertex_incidence(faces, n_points)
    verts = sp.csr_matrix((np.ones(len(seeds)), (np.arange(len(seeds)), seeds)), shape=(len(seeds), n_points))
    for r in range(rings):
        near_faces = verts @ inc                 # faces touching the current vertex set
        if r == rings - 1:
            break
        verts = (near_faces @ inc.T).tocsr()     # their vertices
    near_faces = near_faces.tocsr()
    near_faces.sort_indices()
    counts = np.diff(near_faces.indptr)
    out = np.full((len(seeds), max(int(counts.max(initial=0)), 1)), -1, dtype=np.int64)
    rows = np.repeat(np.arange(len(seeds)), counts)
    cols = np.arange(len(rows)) - np.repeat(near_faces.indptr[:-1], counts)
    out[rows, cols] = near_faces.indices
    return out


def _vertex_rings(faces: np.ndarray, n: int) -> np.ndarray:
    """(n, K) each vertex's neighbours over the mesh's edges (ascending),
    padded by repeating the vertex itself."""
    adj = adjacency(faces, n)
    counts = np.diff(adj.indptr)
    out = np.repeat(np.arange(n)[:, None], max(int(counts.max(initial=0)), 1), axis=1)
    rows = np.repeat(np.arange(n), counts)
    out[rows, np.arange(len(rows)) - np.repeat(adj.indptr[:-1], counts)] = adj.indices
    return out


def _spread(lift: np.ndarray, moved: np.ndarray, adjacency: sp.csr_matrix, movable: np.ndarray, decay: float,
            rings: int) -> tuple[np.ndarray, np.ndarray]:
    """The moves ``lift`` (M, 3) of vertices ``moved`` carried over the
    item mesh (``adjacency`` (M, M) CSR): each ring out, a movable vertex
    takes ``decay`` times its largest neighbour's move where that is larger
    than its own (so no edge takes the whole of a push: a single vertex
    lifted 5 mm out of its 8 mm edges stretched them 1.5x). Returns the
    moves (M, 3) and the vertices that move."""
    out = lift.copy()
    mag = np.zeros(len(out))
    mag[moved] = np.linalg.norm(out[moved], axis=1)
    front = np.asarray(moved, dtype=np.int64)
    touched = [front]
    ptr, idx = adjacency.indptr, adjacency.indices
    for _ in range(rings):
        counts = ptr[front + 1] - ptr[front]
        if not counts.any():
            break
        frm = np.repeat(front, counts)
        at = np.repeat(ptr[front], counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        to = idx[at]
        keep = movable[to]
        frm, to = frm[keep], to[keep]
        cand = decay * mag[frm]
        by = np.lexsort((-cand, to))
        first = np.r_[True, to[by][1:] != to[by][:-1]]
        to, frm, val = to[by][first], frm[by][first], cand[by][first]
        take = val > mag[to]
        to, frm, val = to[take], frm[take], val[take]
        if len(to) == 0:
            break
        out[to] = decay * out[frm]
        mag[to] = val
        front = to
        touched.append(to)
    return out, np.unique(np.concatenate(touched))


def _descend(body: np.ndarray, ring: np.ndarray, points: np.ndarray, start: np.ndarray,
             steps: int = 32) -> np.ndarray:
    """Each point's nearest body vertex, walked from ``start`` over the
    body's edges to a vertex no neighbour of which is nearer (the nearest
    one where the points moved little since ``start`` was found)."""
    cur = np.array(start, dtype=np.int64)
    active = np.arange(len(cur))
    for _ in range(steps):
        cand = ring[cur[active]]                                    # (A, K)
        diff = body[cand] - points[active, None]
        d = np.einsum("akc,akc->ak", diff, diff)
        diff = body[cur[active]] - points[active]
        here = np.einsum("ac,ac->a", diff, diff)
        best = np.argmin(d, axis=1)
        better = d[np.arange(len(active)), best] < here
        if not better.any():
            break
        cur[active[better]] = cand[better, best[better]]
        active = active[better]
    return cur


class SurfaceLayers:
    """``SurfaceLayers(...)(body (N, 3), points (M, 3)) -> points``: outer
    layers kept over the items under them, surface against surface, both
    ways round (see the module); ``pushed`` (M,) says which vertices moved.

    Parameters
    ----------
    layers : list
        A dress plan's per-vertex layers: [(outer item, inner item, sep
        (n_outer,) m, inner vertex of each outer vertex (n_outer,) stacked
        index, -1 for none)] (:func:`layers.layer_gaps`,
        :func:`layers.under_skirts`).
    offsets : (I + 1,) int
        The items' stacked ranges.
    item_faces : (F, 3) int
        The items' stacked triangles.
    body_faces : (T, 3) int; body0 (N, 3)
        The body and its points when built (each outer vertex's body normal
        is its nearest body vertex's there, on the body it is called with).
    items0 : (M, 3)
        The items on ``body0``.
    movable : (M,) bool, optional
        The vertices that may be pushed (not those skinned whole).
    reach : m
        How far above an outer vertex the inner surface is looked for.
    rigid_inner : items (indices) under which nothing is kept by surface
        Rigid items (shoes, hats): a trouser hem lies in and over a shoe
        collar; kept over the collar's triangles, hem vertices came out
        through it elsewhere (``ref_male`` walking on
        ``body_male_muscular_heavy``: of the suit's vertices under the
        shoes, 2.7 -> 12.5 % out through them). The vertex rule keeps those.
    """

    def __init__(self, layers: list, offsets: np.ndarray, item_faces: np.ndarray, body_faces: np.ndarray,
                 body0: np.ndarray, items0: np.ndarray, movable: np.ndarray | None = None, reach: float = REACH,
                 rigid_inner=()):
        items0 = np.asarray(items0, dtype=np.float64)
        m = len(items0)
        offsets = np.asarray(offsets, dtype=np.int64)
        faces = np.asarray(item_faces, dtype=np.int64)
        if items0.ndim != 2 or items0.shape[1] != 3 or len(offsets) < 1 or offsets[-1] != m:
            raise ValueError(f"items0 {items0.shape} and offsets ending at {offsets[-1] if len(offsets) else None}: "
                             "expected (M, 3) points and offsets ending at M")
        if faces.size and (faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= m):
            raise ValueError(f"item_faces {faces.shape}: expected (F, 3) indices into the {m} item points")
        if movable is not None and np.shape(movable) != (m,):
            raise ValueError(f"movable {np.shape(movable)}: expected ({m},)")
        if np.ndim(body0) != 2 or np.shape(body0)[1] != 3 or (np.size(body_faces)
                                                              and int(np.max(body_faces)) >= len(body0)):
            raise ValueError(f"body_faces (up to {int(np.max(body_faces)) if np.size(body_faces) else None}) and "
                             f"body0 {np.shape(body0)}: expected (N, 3) body points the faces index")
        rows, seps, inner = [], [], []
        # each item's connected parts (labels over its own vertices)
        labels = components(faces, m)
        parts = [labels[a:b] for a, b in zip(offsets[:-1], offsets[1:])]
        for o, i, sep, pair in (e for e in layers if len(e) == 4 and e[1] not in set(rigid_inner)):
            oi = np.arange(offsets[o], offsets[o + 1])
            sep = np.broadcast_to(np.asarray(sep, dtype=np.float64), oi.shape)
            # where the reference interleaves the two (an outer vertex at or
            # under the inner surface) the vertex rule alone keeps the relation
            keep = (np.asarray(pair) >= 0) & (sep > 0.0)
            if movable is not None:
                keep &= np.asarray(movable, dtype=bool)[oi]
            if not keep.any():
                continue
            rows.append(oi[keep])
            seps.append(sep[keep])
            # the inner item's parts the plan pairs with (the hot pants, not
            # the top of the same suit)
            ii = np.arange(offsets[i], offsets[i + 1])
            part = parts[i]
            inner.append(ii[np.isin(part, np.unique(part[np.asarray(pair)[keep] - offsets[i]]))])
        self.rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
        self.sep = np.concatenate(seps) if seps else np.zeros(0)
        self.reach = float(reach)
        self.n_points = m
        self.pushed = np.zeros(m, dtype=bool)
        self.active = len(self.rows) > 0
        if not self.active:
            return
        self.faces = faces
        self.adjacency = adjacency(faces, m)
        # per entry, its rows and the inner vertices they may be compared with;
        # each frame, the nearest of those to an outer vertex names its
        # candidate triangles (not the plan's partner, chosen on the reference,
        # nor the nearest when built: the layers slide over each other, 5-12 cm
        # at ref_female_longskirt's hem dressed in a first pose, several cm in
        # a walk)
        ends = np.cumsum([len(r) for r in rows])
        self.groups = [(int(b - len(r)), int(b), ii) for r, b, ii in zip(rows, ends, inner)]
        seeds = np.unique(np.concatenate(inner))
        self.rings = _face_rings(faces, m, seeds)
        self.ring_of = np.full(m, -1, dtype=np.int64)
        self.ring_of[seeds] = np.arange(len(seeds))
        # one normal per pushed vertex: its nearest body vertex's, followed
        # from call to call over the body's edges (a hem's nearest vertex
        # moves from hip to thigh in a stride: the normal of the one found
        # when built saw the skirt 2-5 mm under a top vertex it stood 5-18
        # mm over)
        self.vertices, self.row_vertex = np.unique(self.rows, return_inverse=True)
        body_tree = cKDTree(np.asarray(body0))
        self.body_vertex = body_tree.query(items0[self.vertices])[1]
        self.normals = VertexNormals(body_faces, len(body0))
        self.body_ring = _vertex_rings(np.asarray(body_faces, dtype=np.int64), len(body0))
        # the other way round: inner vertices standing out through the outer
        # item's triangles, between its vertices (hot pants through a coarse
        # skirt), each checked under the outer rows of its entry within
        # ``reach`` and the rows' longest edge of it when built
        edge = np.linalg.norm(items0[faces] - items0[np.roll(faces, 1, axis=1)], axis=2).max(axis=1)
        longest = np.zeros(m)
        np.maximum.at(longest, faces.ravel(), np.repeat(edge, 3))
        under, under_sep, checks = [], [], []
        for a, b, ii in self.groups:
            zone = reach + float(longest[self.rows[a:b]].max())
            d, k = cKDTree(items0[self.rows[a:b]]).query(items0[ii], distance_upper_bound=zone)
            near = np.isfinite(d)
            under.append(ii[near])
            under_sep.append(self.sep[a:b][k[near]])
            checks.append(self.rows[a:b])
        self.under = np.concatenate(under)
        self.under_sep = np.concatenate(under_sep)
        ends = np.cumsum([len(u) for u in under])
        self.under_groups = [(int(e - len(u)), int(e), c) for u, e, c in zip(under, ends, checks)]
        self.outer_movable = (np.ones(m, dtype=bool) if movable is None else np.asarray(movable, dtype=bool))
        self.under_movable = self.outer_movable[self.under]
        self.under_mask = np.zeros(m, dtype=bool)      # the inner vertices a pull may spread to
        self.under_mask[self.under[self.under_movable]] = True
        outer_seeds = np.unique(self.rows)
        self.outer_rings = _face_rings(faces, m, outer_seeds)
        self.outer_ring_of = np.full(m, -1, dtype=np.int64)
        self.outer_ring_of[outer_seeds] = np.arange(len(outer_seeds))
        self.under_body = body_tree.query(items0[self.under])[1]

    def heights(self, body: np.ndarray, points: np.ndarray,
                normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Per row, the inner surface's height over the outer vertex along
        its body normal (-inf where it lies more than the row's separation
        below, or farther than ``reach`` above), and the pushed vertices'
        normals (V, 3)."""
        self.body_vertex = _descend(body, self.body_ring, points[self.vertices], self.body_vertex)
        n = (self.normals(body) if normals is None else normals)[self.body_vertex]
        d = n[self.row_vertex]
        top = points[self.rows] + self.reach * d
        first = first_hits(points, self.faces, self.candidates(points), top, -d, self.reach + self.sep)[0]
        return self.reach - first, n

    def candidates(self, points: np.ndarray) -> np.ndarray:
        """(R, C) each row's candidate inner triangles on ``points``: those
        within two face rings of the nearest allowed inner vertex, padded
        with -1."""
        cand = np.empty((len(self.rows), self.rings.shape[1]), dtype=np.int64)
        for a, b, ii in self.groups:
            near = ii[cKDTree(points[ii]).query(points[self.rows[a:b]])[1]]
            cand[a:b] = self.rings[self.ring_of[near]]
        return cand

    def depths(self, body: np.ndarray, points: np.ndarray, normals: np.ndarray | None = None):
        """Per inner check vertex, the outer item's surface over it along
        its body normal (where met from ``reach`` under it up to its
        separation over it), the triangle met (-1 where none), the normals
        (Q, 3) and the vertices' clearance estimates (Q,) (over their
        nearest body vertex's tangent plane)."""
        self.under_body = _descend(body, self.body_ring, points[self.under], self.under_body)
        n = (self.normals(body) if normals is None else normals)[self.under_body]
        cand = np.empty((len(self.under), self.outer_rings.shape[1]), dtype=np.int64)
        for a, b, rows in self.under_groups:
            near = rows[cKDTree(points[rows]).query(points[self.under[a:b]])[1]]
            cand[a:b] = self.outer_rings[self.outer_ring_of[near]]
        start = points[self.under] - self.reach * n
        t, face = first_hits(points, self.faces, cand, start, n, self.reach + self.under_sep)
        clear = np.einsum("ij,ij->i", points[self.under] - body[self.under_body], n)
        return t - self.reach, face, n, clear

    def __call__(self, body: np.ndarray, points: np.ndarray) -> np.ndarray:
        self.pushed[:] = False
        if not self.active:
            return points
        body_n = self.normals(body)
        h, n = self.heights(body, points, body_n)
        need = h + self.sep
        push = np.zeros(len(self.vertices))
        ok = np.isfinite(need) & (need > 1e-4)
        np.maximum.at(push, self.row_vertex[ok], need[ok])
        sel = push > 0
        points = points.copy()
        lift = np.zeros((self.n_points, 3))     # the outward moves, spread below
        lifted = []
        if sel.any():
            lift[self.vertices[sel]] = push[sel, None] * n[sel]
            lifted.append(self.vertices[sel])
        # inner vertices through the outer triangles: pulled in toward the
        # skin (down to UNDER_MIN_CLEARANCE over it), the pulls spread over
        # the inner item (one by one, the hot pants' fine edges round them
        # stretched 1.5-1.7x on GDQuest's mannequin walking); what a pull
        # cannot take lifts the triangle's corners (lifted only, the coarse
        # skirt's edges stretched: its walk's stretch max 1.45 -> 1.59)
        if len(self.under):
            # against the outer layer as just lifted
            h, face, nu, clear = self.depths(body, points + lift, body_n)
            deficit = np.where(face >= 0, self.under_sep - h, 0.0)
            hit = deficit > 1e-4
            if hit.any():
                room = np.where(self.under_movable, np.clip(clear - UNDER_MIN_CLEARANCE, 0.0, None), 0.0)
                pull = np.minimum(room, deficit) * hit
                drop = np.zeros((self.n_points, 3))
                q = pull > 0
                drop[self.under[q]] = -pull[q, None] * nu[q]
                if q.any():
                    drop, moved = _spread(drop, self.under[q], self.adjacency, self.under_mask, SPREAD_DECAY,
                                          SPREAD_RINGS)
                    # no neighbour pulled deeper than its own room
                    size = np.linalg.norm(drop[self.under], axis=1)
                    scale = np.where(size > room, room / np.maximum(size, 1e-12), 1.0)
                    drop[self.under] *= scale[:, None]
                    points[moved] += drop[moved]
                    self.pushed[moved] = True
                rest = deficit - pull
                up = hit & (rest > 1e-4)
                if up.any():
                    corners = self.faces[face[up]].ravel()
                    amount = np.repeat(rest[up], 3)
                    dirs = np.repeat(nu[up], 3, axis=0)
                    ok = self.outer_movable[corners]
                    # each corner once: its largest lift, along that one's normal
                    order = np.argsort(-amount[ok], kind="stable")
                    c, first = np.unique(corners[ok][order], return_index=True)
                    lift[c] += amount[ok][order][first, None] * dirs[ok][order][first]
                    lifted.append(c)
        if lifted:
            lifted = np.unique(np.concatenate(lifted))
            lift, moved = _spread(lift, lifted, self.adjacency, self.outer_movable, SPREAD_DECAY, SPREAD_RINGS)
            points[moved] += lift[moved]
            self.pushed[moved] = True
        return points


def surface_gaps(layers: list, offsets: np.ndarray, item_faces: np.ndarray, body_faces: np.ndarray,
                 body_points: np.ndarray, points: np.ndarray, movable: np.ndarray | None = None,
                 reach: float = REACH, rigid_inner=()) -> list:
    """A plan's per-vertex layers with each separation lowered to what the
    reference's own surfaces keep.

    :func:`layers.layer_gaps` keeps the reference's interleaving vertex
    against vertex; measured surface against surface (:class:`SurfaceLayers`
    on the reference itself) an outer vertex can lie closer to the inner
    item's triangles, or under them (``ref_male``'s trouser hems over the
    shoe collars: 77 vertices, up to 7.7 mm): there the separation becomes
    the reference's own, so the reference dressed on itself is given back.

    Parameters
    ----------
    layers : list
        [(outer, inner, sep (n_outer,), inner vertex of each outer vertex
        (n_outer,))] as :func:`layers.layer_gaps` returns them.
    offsets, item_faces : the items' stacked ranges and triangles.
    body_faces, body_points : the reference body.
    points : (M, 3) the reference items, stacked.
    movable : (M,) bool, optional; reach : m; rigid_inner : item indices
        As :class:`SurfaceLayers`.

    Returns
    -------
    list
        ``layers`` with the separations lowered where the reference's
        surfaces say so (entries of other lengths unchanged).
    """
    out = []
    for e in layers:
        if len(e) != 4:
            out.append(e)
            continue
        surface = SurfaceLayers([e], offsets, item_faces, body_faces, body_points, points, movable=movable,
                                reach=reach, rigid_inner=rigid_inner)
        if not surface.active:
            out.append(e)
            continue
        o, i, sep, pair = e
        h, _ = surface.heights(body_points, points)
        lower = np.isfinite(h) & (h + surface.sep > 0.0)
        sep = np.array(np.broadcast_to(np.asarray(sep, dtype=np.float64), (offsets[o + 1] - offsets[o],)))
        at = surface.rows[lower] - offsets[o]
        sep[at] = np.minimum(sep[at], -h[lower])
        out.append((o, i, sep, pair))
    return out
