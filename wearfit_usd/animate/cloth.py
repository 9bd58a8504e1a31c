"""Loose parts of items as cloth: an XPBD solve per animation frame.

The K-triangle binding carries every item vertex with the body. Loose parts
(a skirt below the hips, a dress, the tails of a long coat, a cape, long
hair) cannot follow any one body part: bound to the hips, a skirt lets the
legs walk through it; bound to the legs it wraps round one and tears between
them. :class:`ClothSolver` simulates them instead, as cloth:

* which vertices, and how freely: the cloth weight ``w`` of
  :func:`animate.loose.cloth_weights` (0 attached: the waistband, the
  shoulders, the scalp, tight and rigid parts; 1 free);
* the bound position (the plan's evaluation, :class:`frame_eval.FrameEvaluator`)
  is the target each free vertex is softly attached to, with compliance
  ``ATTACH_ALPHA * w ** ATTACH_POWER``: stiff next to the attachment line,
  soft where the cloth hangs free (there it only keeps the garment's cut:
  a skirt keeps its flare, hair its shape, and settles back to it);
* the edges keep their lengths in the rest state (stiff against stretch,
  softer against compression): the static dress of the first frame, or for
  the hanging parts (skirts, hair) the static dress on the bind pose given to
  :meth:`ClothSolver.set_rest` (the relaxed cut: ``animate`` does); tethers
  keep every free vertex within ``1 + TETHER_SLACK`` of its rest distance
  along the cloth from the attachment;
* the body is the collider: every free vertex, and the midpoint of every
  edge longer than ``EDGE_SAMPLE_LENGTH``, stays ``MARGIN`` outside the skin
  of this frame (or its frame-0 clearance where that is less), with
  friction; and over the bound items under the cloth wherever it swings
  (:func:`inner_layer_field`: shorts under a skirt), not just the skin;
* inertia: velocities carry over from frame to frame (gravity, damping
  relative to the bound motion), so a skirt swings after a turn and hair
  settles after a nod.

The dynamics are XPBD (Macklin, Mueller, Chentanez 2016); the equations and
the substep loop are in :mod:`kernels.cloth`. A frame of ``dt`` seconds is
split into ``ceil(dt / MAX_SUBSTEP)`` substeps, the body and the targets
moving linearly over them. The nearest body vertex of each collision sample
near the body is searched on a grid every ``SEEK_INTERVAL`` seconds (within
the distance the body can travel until the next search; every sample each
``RESEED_EVERY`` searches) and followed by a walk over the body's vertex
graph every frame in between.

The cloth starts at rest on the target's bind pose and is carried into the
first frame by :meth:`ClothSolver.preroll` (the static dress of a walking
pose can have a leg through a skirt bound to the hips: no collision could
tell from there which side the cloth belongs on). A clip does not start at
rest: the shot's first step gives each piece of cloth the mean velocity of
its attachment line over that step (as if it had been moving with the body
before the clip began). Started at rest, it was left behind by a body
already walking at 1.2 m/s: a ponytail flew back nearly level in the first
six frames of the CMU walk and took a second to settle. Chosen by
measurement (CMU walk, run, Daz walk and pirouette, the first 45 frames
from ``--start auto``, the three every-clip sweep pairs; figures over issue
17's limits): at rest 33, the attachment line's mean velocity 30. Not kept,
measured on the same clips from clip frame 0 (the converters' T-pose; at
rest 41, the line's mean velocity 36): the whole body's best rigid motion
(41: its turn swung the ponytail, 0.7 m above the body's centre), the
body's mean velocity (40), the line's rigid motion (37), each vertex's
target velocity (36; and on the long skirt starting mid-crouch in the CMU
punch new penetrations 0.84 -> 1.12 %: a hem's targets extrapolate the
hips' turn 70 cm down).

Measured (CMU walk, ``ref_female_longskirt`` on ``body_female_heavy``, 2,075
simulated vertices, 45 frames at 30 fps; see ``docs/motion_loose_parts.md``):
the skirt's stretch against the static dress on the bind pose, beyond the
body's own, p99 1.61x / max 2.96x in the worst frame (2.35x / 5.7x before the
relaxed-cut rest state, the tethers and 3 passes). Most of what remains is
the hem at the longest stride: the legs' hull there is longer than the hem.

Usage: ``solver = ClothSolver(plan, body_faces, body_points0, item_points0)``
on the dressed frame 0, then ``points = solver.step(body_f, bound_f, dt)``
for each following frame. Arrays are numpy; metres and seconds (internal
space, Y up).
"""
from __future__ import annotations

import math
import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from ..dress import regions as R
from ..dress.corrections import smoothstep
from ..geometry.closest import VertexNormals
from ..geometry.mesh import adjacency, similarity_fit
from ..kernels import HAVE_NUMBA, RadiusGrid
from ..kernels.cloth import (
    ClothBody,
    ClothEdges,
    ClothParams,
    ClothSamples,
    ClothState,
    ClothTargets,
    ClothTethers,
    cloth_frame,
    make_scratch,
)
from .loose import cloth_weights

GRAVITY = (0.0, -9.81, 0.0)  # m/s^2, internal space (Y up)
MAX_SUBSTEP = 1.0 / 240.0    # s: longest substep
ITERATIONS = 3               # passes over the cloth's own constraints per substep (1: the pencil skirt stretched 1.3x)
ATTACH_ALPHA = 0.2           # s^2: attachment compliance of fully free vertices (a ~3 s swing; 0.02 pulled a
                             # skirt's side out after a binding that followed the hand beside it)
ATTACH_POWER = 2.0           # compliance ~ w^power: stiff near the attachment line
STRETCH_ALPHA = 0.0          # s^2: edges against stretch (0: as stiff as the substeps allow)
COMPRESS_ALPHA = 1e-4        # s^2: edges against compression (cloth buckles)
DAMPING = 2.0                # 1/s: decay of the velocity relative to the bound motion
FRICTION = 0.3               # Coulomb coefficient against the skin
MARGIN = 0.005               # m kept between the cloth and the skin
PREROLL_FRAMES = 20          # frames from the bind pose to the first frame (see ClothSolver.preroll)
SETTLE_FRAMES = 10           # frames at rest on the first frame after that
EDGE_SAMPLE_LENGTH = 0.03    # m: edges longer than this get a collision sample at their midpoint
#: s between grid searches of the nearest body vertex of the samples near the
#: body. 1/30 -> 1/15 (session 27; every other frame at 30 fps, the kernel's
#: walk follows between): the long skirt's walk 2.3-2.45 -> 1.93-1.97 us a
#: cloth vertex (benchmarks' cloth row, same run); the every-clip sweep
#: 78 -> 76 figures over the limits, the cloth's figures moved both ways as
#: any change to its collisions moves them (the long skirt in 131_01:
#: separation p95 22.5 -> 11.3 mm, stretch max 3.19 -> 2.77; in the jump
#: coverage loss 6.3 -> 7.5 %; ponytail01's worst stretch max over the
#: clips 2.86 -> 2.93)
SEEK_INTERVAL = 2.0 / 30.0
RESEED_EVERY = 8             # searches between searches of every sample (the kernel walks from them between)
SEED_REACH = 0.5             # m: the first search of each sample's nearest body vertex
GRID_CELL = 0.05             # m: cell of the nearest-body-vertex grid (0.02: the search took 3x as long)
REACH = 0.02                 # m: body farther than this (plus its motion this frame and gap) is not tested
CARRY_RINGS = 4              # edges the guard's pushes reach into the cloth's targets (PushCarry)
CARRY_DECAY = 0.7            # per ring
TETHER_SLACK = 0.02          # a free vertex stays within (1 + this) x its rest distance along the cloth from its anchor


def colour_edges(edges: np.ndarray, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Colour edges so that no two edges of one colour share a vertex.

    Greedy by rounds: among the uncoloured edges that touch no vertex used
    by this colour yet, those with the highest random priority at both of
    their vertices join the colour (an independent set, Luby-style); a colour
    is full when no edge can join.

    Parameters
    ----------
    edges : (E, 2) int vertex pairs; n: number of vertices.

    Returns
    -------
    order : (E,) edge indices sorted by colour.
    colour_ptr : (C + 1,) start of each colour in ``order``.
    """
    e = np.asarray(edges, dtype=np.int64)
    m = len(e)
    pri = np.random.default_rng(seed).permutation(m)
    colour = np.full(m, -1, dtype=np.int64)
    c = 0
    while (colour < 0).any():
        used = np.zeros(n, dtype=bool)
        while True:
            cand = np.flatnonzero((colour < 0) & ~used[e[:, 0]] & ~used[e[:, 1]])
            if len(cand) == 0:
                break
            best = np.full(n, -1, dtype=np.int64)
            np.maximum.at(best, e[cand, 0], pri[cand])
            np.maximum.at(best, e[cand, 1], pri[cand])
            win = cand[(best[e[cand, 0]] == pri[cand]) & (best[e[cand, 1]] == pri[cand])]
            colour[win] = c
            used[e[win, 0]] = True
            used[e[win, 1]] = True
        c += 1
    order = np.argsort(colour, kind="stable")
    colour_ptr = np.searchsorted(colour[order], np.arange(c + 1))
    return order, colour_ptr.astype(np.int64)


def body_graph(faces: np.ndarray, n: int, keep: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The body's vertex graph: CSR (indptr (n + 1,), indices) with sorted
    neighbours, and the same as an (n, D) table padded with -1. ``keep``:
    only these vertices (indices into the body; the graph is then over
    ``len(keep)`` vertices numbered as in ``keep``)."""
    a = adjacency(faces, n).tocsr()
    if keep is not None:
        a = a[keep][:, keep].tocsr()
        n = len(keep)
    a.sort_indices()
    indptr = a.indptr.astype(np.int64)
    indices = a.indices.astype(np.int64)
    deg = np.diff(indptr)
    table = np.full((n, max(int(deg.max(initial=0)), 1)), -1, dtype=np.int64)
    table[np.repeat(np.arange(n), deg), np.arange(len(indices)) - np.repeat(indptr[:-1], deg)] = indices
    return indptr, indices, table


def tethers(edges: np.ndarray, rest: np.ndarray, n_free: int, n: int, slack: float | None) -> ClothTethers:
    """Each free particle's anchor, the kinematic particle (index >= n_free)
    nearest to it along the cloth's edges (Dijkstra over the rest lengths),
    and the tether's length, that distance times ``1 + slack``.

    Parameters
    ----------
    edges : (E, 2) particle pairs; rest (E,) their lengths; n particles, the
        first n_free simulated. slack: None for no tethers.

    Returns
    -------
    :class:`kernels.cloth.ClothTethers`: anchor (n_free,) (-1 where no
    kinematic particle is reachable, or no tethers), length (n_free,).
    """
    anchor = np.full(n_free, -1, dtype=np.int64)
    length = np.full(n_free, np.inf)
    if slack is None or n <= n_free or len(edges) == 0:
        return ClothTethers(anchor, length)
    g = sp.csr_matrix((np.maximum(rest, 1e-9), (edges[:, 0], edges[:, 1])), shape=(n, n))
    dist, _, src = dijkstra(g, directed=False, indices=np.arange(n_free, n), min_only=True,
                            return_predecessors=True)
    ok = np.isfinite(dist[:n_free]) & (src[:n_free] >= 0)
    anchor[ok] = src[:n_free][ok]
    length[ok] = dist[:n_free][ok] * (1.0 + float(slack))
    return ClothTethers(anchor, np.ascontiguousarray(length))


def tangent_clearance(points: np.ndarray, body_points: np.ndarray, body_normals: np.ndarray,
                      tree: cKDTree | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each point's nearest body vertex (P,) and its clearance (P,) along
    that vertex's unit normal: the estimate the collision uses (the nearest
    vertex's tangent plane). ``tree``: a KD-tree over ``body_points`` if one
    is already built."""
    _, near = (cKDTree(body_points) if tree is None else tree).query(points)
    return near, np.einsum("ij,ij->i", points - body_points[near], body_normals[near])


LAYER_REACH = 0.03  # m: bound vertices of other items this near a cloth sample may lie under it
LAYER_GAP = 0.003   # m kept between the cloth and such a layer


def inner_layer_margin(plan, weights: np.ndarray, item_points: np.ndarray, particles: np.ndarray,
                       samples: np.ndarray, sample_points: np.ndarray, sample_clearance: np.ndarray,
                       body_points: np.ndarray, body_normals: np.ndarray, tree: cKDTree | None = None) -> np.ndarray:
    """(S,) the clearance each cloth sample keeps over the items under it.

    The cloth collides with the body only; over a bound layer of another item
    (a top whose hem hangs over the hips, shorts under a skirt) kept at
    MARGIN from the skin, the swinging skirt sank under that layer and it
    showed through (the long skirt in the arms-held-high clip: the top's
    orange in patches below the waistband). A sample keeps, instead, the
    largest clearance of the bound vertices of other items within
    ``LAYER_REACH`` that are nearer the skin than it is in the static dress,
    plus ``LAYER_GAP``, at most its own static clearance (0 where none).

    Parameters
    ----------
    plan : the dress plan (its item offsets).
    weights : (M,) cloth weights (0: bound).
    item_points : (M, 3) all items dressed at frame 0.
    particles : (P,) the cloth's particles (item rows); samples (S, 2) their
        pairs (a particle twice: a vertex sample); sample_points (S, 3) and
        sample_clearance (S,) at frame 0.
    body_points, body_normals : (C, 3) the collider's vertices and unit
        normals at frame 0; tree: a KD-tree over ``body_points``, optional.
    """
    out = np.zeros(len(samples))
    offsets = getattr(plan, "offsets", None)
    bound = np.flatnonzero(np.asarray(weights) <= 0)
    if offsets is None or len(bound) == 0 or len(samples) == 0:
        return out
    item_of = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    bp = np.asarray(item_points, dtype=np.float64)[bound]
    _, bclear = tangent_clearance(bp, body_points, body_normals, tree)
    k = int(min(16, len(bound)))
    d, idx = cKDTree(bp).query(sample_points, k=k, distance_upper_bound=LAYER_REACH)
    d, idx = np.asarray(d).reshape(len(samples), k), np.asarray(idx).reshape(len(samples), k)
    found = idx < len(bound)
    safe = np.where(found, idx, 0)
    own = item_of[particles[samples[:, 0]]]
    under = found & (item_of[bound[safe]] != own[:, None]) & (bclear[safe] < sample_clearance[:, None] - 1e-3)
    need = np.where(under, bclear[safe], -np.inf).max(axis=1) + LAYER_GAP
    return np.where(np.isfinite(need), np.clip(need, 0.0, np.maximum(sample_clearance, 0.0)), 0.0)


LAYER_SPOT = 0.04   # m: footprints this near are over the same spot of the skin (a coarse skirt's edges are 3-5 cm)
LAYER_INHERIT = 0.06  # m: a vertex with no cloth over its spot is decided by its item's decided vertices this near
LAYER_FOOT = 0.03   # m: an inner vertex lifts the body vertices this near its footprint
LAYER_CAP = 0.03    # m: the highest inner layer kept over (a loose top's hem over the hips)


def inner_layer_field(plan, weights: np.ndarray, item_points: np.ndarray, particles: np.ndarray,
                      samples: np.ndarray, sample_clearance: np.ndarray, sample_vertex: np.ndarray,
                      body_points: np.ndarray, body_normals: np.ndarray, tree: cKDTree | None = None):
    """The clearance each cloth item keeps over the items under it, as a
    field over the collider's vertices: wherever the cloth swings.

    :func:`inner_layer_margin` gives each sample the height of the layers
    under it in the static dress. A skirt's hem that hangs free there and
    swings onto a thigh meets shorts it never lay over, and they came
    through it (the long skirt walking: the hot pants' orange in patches
    through the blue). Here every body vertex carries the height of what
    lies under the cloth item over it.

    Which vertices are under a cloth item is decided per vertex, not per
    item (one suit is hot pants under a skirt and a top whose hem hangs over
    it), as :mod:`dress.layers` compares layers: over the same spot of the
    skin. Each vertex's footprint is its nearest body vertex; a bound vertex
    of another item is under the cloth item when the cloth's vertex with the
    nearest footprint (within ``LAYER_SPOT``) is farther from the skin than
    it (by 1 mm). A vertex with no cloth over its spot (the inner thighs
    under a skirt) takes the answer of the nearest vertex of its own item
    that has one, within ``LAYER_INHERIT``. Rigid items (shoes, a hat) are
    not layers: a sole stands 2-3 cm off the foot.

    The under vertices' clearance (0 to ``LAYER_CAP``) plus ``LAYER_GAP`` is
    spread to the body vertices within ``LAYER_FOOT`` of their footprint
    (the largest where several). A sample keeps ``field[row, h] - allow``
    over its current nearest body vertex ``h`` (the kernel,
    :func:`kernels.cloth.cloth_frame`); ``allow`` is how far the static dress
    has it under the field at frame 0 (a waistband interleaved with a top's
    hem stays as dressed; 0 for a sample inside the body there).

    Parameters
    ----------
    plan : the dress plan (its ``offsets``, ``items`` and wholly rigid items).
    weights : (M,) cloth weights (0: bound).
    item_points : (M, 3) all items dressed at frame 0.
    particles : (P,) the cloth's particles (item rows); samples (S, 2) their
        pairs; sample_clearance (S,) and sample_vertex (S,) each sample's
        clearance and nearest collider vertex at frame 0.
    body_points, body_normals : (C, 3) the collider's vertices and unit
        normals at frame 0; tree: a KD-tree over ``body_points``, optional.

    Returns
    -------
    layer_row : (S,) int64, the field row of each sample's item (-1: none).
    allow : (S,) metres.
    field : (R, C) metres (R >= 1; one row of zeros when nothing lies under
        a cloth item).
    """
    n_s, n_c = len(samples), len(body_points)
    rows = np.full(n_s, -1, dtype=np.int64)
    allow = np.zeros(n_s)
    offsets, items = getattr(plan, "offsets", None), getattr(plan, "items", None)
    if offsets is None or items is None or n_s == 0 or n_c == 0:
        return rows, allow, np.zeros((1, n_c))
    pts = np.asarray(item_points, dtype=np.float64)
    w = np.asarray(weights)
    item_of = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    own = item_of[particles[samples[:, 0]]]
    whole = plan.wholly_rigid() if hasattr(plan, "wholly_rigid") else set()
    rigid = np.isin(item_of, [i for i, m in enumerate(items) if getattr(m, "name", None) in whole])
    tree = cKDTree(body_points) if tree is None else tree
    foot, clear = tangent_clearance(pts, body_points, body_normals, tree)
    field = []
    for item in np.unique(own):
        mine = np.flatnonzero(item_of == item)
        spots = cKDTree(body_points[foot[mine]])
        under = np.zeros(len(pts), dtype=bool)
        for other in np.unique(item_of[(item_of != item) & (w <= 0) & ~rigid]):
            v = np.flatnonzero((item_of == other) & (w <= 0))
            d, j = spots.query(body_points[foot[v]], distance_upper_bound=LAYER_SPOT)
            decided = np.isfinite(d)
            if not decided.any():
                continue
            is_under = decided & (clear[mine[np.where(decided, j, 0)]] > clear[v] + 1e-3)
            if not decided.all():  # no cloth over the spot: as the nearest decided vertex of the item
                dk, k = cKDTree(pts[v[decided]]).query(pts[v[~decided]], distance_upper_bound=LAYER_INHERIT)
                near = np.isfinite(dk)
                is_under[np.flatnonzero(~decided)[near]] = is_under[decided][k[near]]
            under[v[is_under]] = True
        if not under.any():
            continue
        u = np.flatnonzero(under)
        # the highest over each footprint, then over every body vertex within LAYER_FOOT of one
        feet, at = np.unique(foot[u], return_inverse=True)
        top = np.zeros(len(feet))
        np.maximum.at(top, at, np.clip(clear[u], 0.0, LAYER_CAP))
        near = tree.sparse_distance_matrix(cKDTree(body_points[feet]), LAYER_FOOT, output_type="coo_matrix")
        row = np.zeros(n_c)
        row[feet] = top + LAYER_GAP
        np.maximum.at(row, near.row, top[near.col] + LAYER_GAP)
        sel = own == item
        rows[sel] = len(field)
        allow[sel] = np.where(sample_clearance[sel] >= 0.0,
                              np.maximum(row[sample_vertex[sel]] - sample_clearance[sel], 0.0), 0.0)
        field.append(row)
    if not field:
        return rows, allow, np.zeros((1, n_c))
    return rows, allow, np.ascontiguousarray(np.stack(field))


class PushCarry:
    """The penetration guard's pushes on bound item vertices carried onto the
    cloth's targets next to them.

    The guard (:class:`animate.penetration_guard.PenetrationGuard`) moves the
    bound vertices (cloth weight 0) out of the body; the cloth's vertices
    beside them are attached to their bound positions, which the guard does
    not see. Pushed after the cloth, a bound vertex stood out of its cloth
    neighbours (a trouser leg at a bending knee, ``male_casualsuit01`` in the
    CMU walk: one vertex pushed 11 mm, its neighbour 3 mm away at weight
    0.001 not at all). Carried, the target of each cloth vertex ``r`` edges
    from the guarded ones (``r <= rings``) moves by

        d_r = decay * mean(d over its neighbours nearer to them),
        shift = (1 - w) d_r

    ring after ring from the guard's displacements ``d_0``: fading away from
    the attachment, and by the cloth weight ``w`` (a vertex hanging free
    keeps its own target; the cloth's edges carry it).

    Parameters
    ----------
    neighbours : (M, M) sparse, the items' vertex adjacency (the plan's
        ``mesh.neighbours``).
    guarded_rows : (B,) the item rows the guard moves.
    weights : (M,) cloth weights (:func:`loose.cloth_weights`).
    rings : edges the pushes reach into the cloth; decay : per ring.

    ``carry(shift (B, 3)) -> (C, 3)``, the shifts of the rows ``carry.rows``.
    """

    def __init__(self, neighbours, guarded_rows: np.ndarray, weights: np.ndarray, rings: int = CARRY_RINGS,
                 decay: float = CARRY_DECAY):
        w = np.asarray(weights, dtype=np.float64)
        m = len(w)
        guarded_rows = np.asarray(guarded_rows, dtype=np.int64)
        if neighbours.shape != (m, m):
            raise ValueError(f"neighbours is {neighbours.shape} for {m} item points")
        if rings < 1 or not 0.0 < decay <= 1.0:
            raise ValueError(f"rings {rings} (>= 1), decay {decay} (0 < decay <= 1)")
        a = sp.csr_matrix(neighbours, dtype=np.float64)
        a.data[:] = 1.0
        cloth = w > 0
        cloth[guarded_rows] = False
        # ring r: the cloth rows r edges from the guarded ones
        ring = np.full(m, -1, dtype=np.int64)
        ring[guarded_rows] = 0
        for r in range(1, rings + 1):
            reached = (a @ (ring >= 0).astype(np.float64)) > 0
            ring[reached & cloth & (ring < 0)] = r
        carried = np.flatnonzero(ring > 0)
        self.rows = carried[np.argsort(ring[carried], kind="stable")]
        self.guarded = guarded_rows
        col = np.full(m, -1, dtype=np.int64)
        col[guarded_rows] = np.arange(len(guarded_rows))
        col[self.rows] = len(guarded_rows) + np.arange(len(self.rows))
        n = len(guarded_rows) + len(self.rows)
        # per ring: the mean over the neighbours one ring nearer, times decay
        self._steps = []
        for r in range(1, rings + 1):
            rows = np.flatnonzero(ring == r)
            if len(rows) == 0:
                break
            sub = a[rows].tocoo()
            keep = ring[sub.col] == r - 1
            cnt = np.bincount(sub.row[keep], minlength=len(rows)).astype(np.float64)
            op = sp.csr_matrix((decay / cnt[sub.row[keep]], (sub.row[keep], col[sub.col[keep]])),
                               shape=(len(rows), n))
            self._steps.append((col[rows], op))
        self._fade = (1.0 - np.clip(w[self.rows], 0.0, 1.0))[:, None]

    def __len__(self) -> int:
        return len(self.rows)

    def __call__(self, shift: np.ndarray) -> np.ndarray:
        shift = np.asarray(shift, dtype=np.float64)
        if shift.shape != (len(self.guarded), 3):
            raise ValueError(f"shift is {shift.shape}, expected ({len(self.guarded)}, 3)")
        d = np.zeros((len(self.guarded) + len(self.rows), 3))
        d[:len(self.guarded)] = shift
        for cols, op in self._steps:
            d[cols] = op @ d
        return self._fade * d[len(self.guarded):]


def default_collider(plan, n: int) -> np.ndarray:
    """(n,) bool: the body vertices loose parts collide with: all but the
    arms when the plan knows the body's regions. A hand hanging beside a
    skirt would otherwise catch it and throw it out in a flap (and a hand
    between skirt and hip, with the cloth on both sides of it, has no side
    to push it to); a hand sinking into the cloth is the lesser evil."""
    keep = np.ones(n, dtype=bool)
    regions = getattr(plan, "regions", None)
    labels = None if regions is None else regions.body
    if labels is not None and len(labels) == n:
        keep &= ~np.isin(labels, [R.LEFT_ARM, R.RIGHT_ARM])
    return keep


class ClothSolver:
    """XPBD cloth for the loose vertices of a dress plan (module docstring).

    Parameters
    ----------
    plan : the :class:`redress.DressPlan` the frames are evaluated with
        (its items, edges, looseness, skirt items, rigid parts).
    body_faces : (T, 3) body triangles.
    body_points0 : (N, 3) body at frame 0.
    item_points0 : (M, 3) all item points dressed at frame 0 (the static
        dress: rest lengths and the starting state).
    weights : (M,) cloth weights (default :func:`loose.cloth_weights`).
    collider : (N,) bool or indices, the body vertices the cloth collides
        with (default :func:`default_collider`).
    rest_points : (M, 3) the rest state of the hanging part of the loose items
        (as :meth:`set_rest`), on the body's bind pose; default
        ``item_points0`` for all.
    compiled : numba kernel (default: when installed) or its numpy twin.
    Other keywords override the module constants of the same name.
    """

    def __init__(self, plan, body_faces: np.ndarray, body_points0: np.ndarray, item_points0: np.ndarray,
                 weights: np.ndarray | None = None, rest_points: np.ndarray | None = None, compiled: bool | None = None,
                 gravity=GRAVITY, max_substep: float = MAX_SUBSTEP, iterations: int = ITERATIONS,
                 attach_alpha: float = ATTACH_ALPHA, attach_power: float = ATTACH_POWER,
                 stretch_alpha: float = STRETCH_ALPHA, compress_alpha: float = COMPRESS_ALPHA,
                 damping: float = DAMPING, friction: float = FRICTION, margin: float = MARGIN,
                 reach: float = REACH, edge_samples: bool = True, collider: np.ndarray | None = None,
                 tether_slack: float | None = TETHER_SLACK):
        pts0 = np.ascontiguousarray(item_points0, dtype=np.float64)
        body0 = np.ascontiguousarray(body_points0, dtype=np.float64)
        self.faces = np.ascontiguousarray(body_faces, dtype=np.int64)
        self.compiled = HAVE_NUMBA if compiled is None else bool(compiled and HAVE_NUMBA)
        w = cloth_weights(plan) if weights is None else np.asarray(weights, dtype=np.float64)
        self.weights = w
        self.free = np.flatnonzero(w > 0)
        self.n_free = len(self.free)
        self.gravity = np.asarray(gravity, dtype=np.float64)
        self.max_substep, self.iterations = float(max_substep), int(iterations)
        self.stretch_alpha, self.compress_alpha = float(stretch_alpha), float(compress_alpha)
        self.damping, self.friction, self.reach = float(damping), float(friction), float(reach)
        self.timings = {"frames": 0, "solve_s": 0.0, "solve_cpu_s": 0.0}
        self.rest_points = None
        self._launch = False  # the next step starts the cloth moving with its attachment line (after preroll)
        if self.n_free == 0:
            return
        e = np.asarray(plan.mesh.edges, dtype=np.int64)
        free_mask = w > 0
        e = e[free_mask[e[:, 0]] | free_mask[e[:, 1]]]
        # particles: the free vertices, then the bound vertices they share edges with
        kin = np.setdiff1d(e.ravel(), self.free)
        self.particles = np.concatenate([self.free, kin])
        local = np.full(len(w), -1, dtype=np.int64)
        local[self.particles] = np.arange(len(self.particles))
        le = local[e]
        order, self.colour_ptr = colour_edges(le, len(self.particles))
        self.edges = np.ascontiguousarray(le[order])
        x0 = pts0[self.particles]
        xr = x0
        self.rest = np.linalg.norm(xr[self.edges[:, 0]] - xr[self.edges[:, 1]], axis=1)
        self.inv_m = np.zeros(len(self.particles))
        self.inv_m[:self.n_free] = 1.0
        self.att_alpha = float(attach_alpha) * w[self.free] ** float(attach_power)
        self.tether_slack = tether_slack
        self.tethers = tethers(self.edges, self.rest, self.n_free, len(self.particles), tether_slack)
        # the cloth's connected pieces (a skirt, a ponytail), each with its
        # attachment line (its bound particles): see _start_moving
        n_p = len(self.particles)
        graph = sp.csr_matrix((np.ones(len(self.edges)), (self.edges[:, 0], self.edges[:, 1])), shape=(n_p, n_p))
        self.piece = connected_components(graph, directed=False)[1]
        if rest_points is not None:
            self.set_rest(rest_points)
        # collision samples: the free particles and the midpoints of the
        # edges (a knee between the vertices of a coarse skirt meets one);
        # the particles are one colour, the edges keep theirs
        own = np.repeat(np.arange(self.n_free), 2).reshape(-1, 2)
        if edge_samples:
            # free edges only: a bound end inside the body (a thigh through
            # the hips' part) would throw its free end out twice as far
            both = (self.edges < self.n_free).all(axis=1) & (self.rest > EDGE_SAMPLE_LENGTH)
            col = np.repeat(np.arange(len(self.colour_ptr) - 1), np.diff(self.colour_ptr))[both]
            self.samples = np.ascontiguousarray(np.concatenate([own, self.edges[both]]), dtype=np.int64)
            self.sample_ptr = np.concatenate([[0], self.n_free + np.searchsorted(
                col, np.arange(len(self.colour_ptr)))]).astype(np.int64)
        else:
            self.samples = np.ascontiguousarray(own, dtype=np.int64)
            self.sample_ptr = np.array([0, self.n_free], dtype=np.int64)
        # body: the collider's vertices, their graph, normals, nearest-vertex grid
        if collider is None:
            collider = default_collider(plan, len(body0))
        self.collider = np.flatnonzero(collider) if np.asarray(collider).dtype == bool else np.asarray(collider)
        self.collider = np.ascontiguousarray(self.collider, dtype=np.int64)
        self._normals = VertexNormals(self.faces, len(body0))
        self.adjacency = body_graph(self.faces, len(body0), self.collider)
        body0 = np.ascontiguousarray(body0[self.collider])
        be = np.linalg.norm(body0[self.adjacency[1]] - body0[np.repeat(np.arange(len(body0)),
                                                                        np.diff(self.adjacency[0]))], axis=1)
        # the skin can be this much nearer than the nearest body vertex (the
        # centre of a triangle is 1/sqrt(3) of its side from its corners)
        self.gap = 0.6 * float(np.percentile(be, 99)) if len(be) else 0.0
        self.b0 = body0
        self.n0 = self._body_normals(body_points0)
        self.grid = RadiusGrid(body0, reach, cell=GRID_CELL)
        # clearance kept: MARGIN, or less where the static dress is closer
        # (same estimate as the collision: the nearest vertex's tangent plane)
        self.x = np.ascontiguousarray(x0)
        q = self._sample_points()
        tree = cKDTree(body0)
        near, est = tangent_clearance(q, body0, self.n0, tree)
        self.margin = np.clip(est, 0.0, float(margin))
        # over another item (a top's hem, shorts under a skirt) the cloth
        # keeps its clearance above that layer, not the skin's MARGIN
        self.margin = np.maximum(self.margin, inner_layer_margin(plan, w, pts0, self.particles, self.samples, q,
                                                                 est, body0, self.n0, tree))
        # and wherever it swings, over the items the plan layers under it
        self.layer_row, self.allow, self.layer = inner_layer_field(plan, w, pts0, self.particles, self.samples, est,
                                                                   near, body0, self.n0, tree)
        self.top = np.where(self.layer_row >= 0, self.layer.max(axis=1)[np.maximum(self.layer_row, 0)] - self.allow,
                            0.0)
        self.top = np.ascontiguousarray(np.maximum(self.margin, self.top))
        # the nearest-vertex searches must reach the largest clearance kept
        self.reach = max(self.reach, float(self.top.max(initial=0.0)) + 0.005)
        self.v = np.zeros((self.n_free, 3))
        self.t0 = x0.copy()
        self.hint = np.full(len(self.samples), -1, dtype=np.int64)
        self.clear = np.full(len(self.samples), -np.inf)
        self._seek(SEED_REACH)
        self._frame, self._since = 1, 0.0
        self._scratch = make_scratch(len(self.edges), self.n_free, len(self.particles), len(self.samples))

    @property
    def hanging(self) -> np.ndarray:
        """(H,) the free vertices that hang (cloth weight >= 1/2): the part
        :meth:`set_rest` applies to."""
        return self.free[self.weights[self.free] >= 0.5]

    def set_rest(self, points: np.ndarray, keep: bool = True) -> None:
        """Take the edge rest lengths (and the tethers) of the hanging part
        of the loose items (cloth weight >= 1/2: a skirt below the hips,
        hair below the scalp) from the items (M, 3) on the body's bind pose;
        ``keep``: :meth:`preroll` starts that part from them, turned onto
        the body. The part near the attachment keeps the lengths of the
        dress it was built on.

        The dress of a posed first frame can be stretched where the cloth
        hangs: a skirt round a leg forward, and hair bound to the head and
        the back together (``ponytail01`` dressed in the CMU walk's first
        pose on ``body_female_thin``: 18 mm edges at 35 mm). Resting on it,
        the cloth kept that stretch in every frame (every-clip sweep, the
        ponytail's worst frame's stretch beyond the body's: p99 1.65 -> 1.49,
        max 5.9 -> 4.2 in the pirouette with the hair's rest from the bind
        pose too, not only the skirts')."""
        if keep:
            self.rest_points = np.asarray(points, dtype=np.float64)
        if self.n_free == 0:
            return
        xr = np.asarray(points, dtype=np.float64)[self.particles]
        rest = np.linalg.norm(xr[self.edges[:, 0]] - xr[self.edges[:, 1]], axis=1)
        # only where the skirt hangs (both ends cloth weight >= 1/2): near
        # the attachment line the cloth keeps the dress it is attached to
        # (the binding's), or the two fight (a skirt's side pulled out
        # where the binding follows the hand beside it)
        pe = self.particles[self.edges]
        hang = (self.weights[pe] >= 0.5).all(axis=1)
        self.rest = np.where(hang, rest, self.rest)
        self.tethers = tethers(self.edges, self.rest, self.n_free, len(self.particles), self.tether_slack)

    def _body_normals(self, body_points: np.ndarray) -> np.ndarray:
        """(C, 3) unit normals of the collider's vertices on the whole body (N, 3)."""
        return np.ascontiguousarray(self._normals(np.asarray(body_points, dtype=np.float64))[self.collider])

    def _sample_points(self) -> np.ndarray:
        """(S, 3) the collision samples at the current positions."""
        return 0.5 * (self.x[self.samples[:, 0]] + self.x[self.samples[:, 1]])

    def _seek(self, radius: float, rows: np.ndarray | None = None) -> None:
        """Nearest body vertex (on ``self.b0``'s grid) of the collision
        samples ``rows`` (default all) within ``radius``; the search starts
        from the current hints, samples with none within reach keep theirs
        (the walk in the kernel follows them from there)."""
        rows = np.arange(len(self.samples)) if rows is None else rows
        if len(rows) == 0:
            return
        sp = self.samples[rows]
        q = 0.5 * (self.x[sp[:, 0]] + self.x[sp[:, 1]])
        idx, dist = self.grid.nearest(q, hint=self.hint[rows], radius=radius)
        found = idx >= 0
        self.hint[rows[found]] = idx[found]
        self.clear[rows] = np.where(found, dist, np.maximum(self.clear[rows], radius))

    @property
    def active(self) -> bool:
        """Whether there is anything to simulate."""
        return self.n_free > 0

    def substeps(self, dt: float) -> int:
        """Substeps for a frame of ``dt`` seconds."""
        return max(1, int(math.ceil(dt / self.max_substep - 1e-9)))

    def reset(self, body_points: np.ndarray, item_points: np.ndarray) -> None:
        """Restart at rest from the items (M, 3) on the body (N, 3)."""
        if self.n_free == 0:
            return
        self.b0 = np.ascontiguousarray(np.asarray(body_points, dtype=np.float64)[self.collider])
        self.n0 = self._body_normals(body_points)
        self.grid.update(self.b0)
        self.x = np.ascontiguousarray(np.asarray(item_points, dtype=np.float64)[self.particles])
        self.t0 = self.x.copy()
        self.v[:] = 0.0
        self._launch = False
        self.clear[:] = -np.inf
        self.hint[:] = -1
        self._seek(SEED_REACH)
        self._frame, self._since = 1, 0.0

    def preroll(self, body_from: np.ndarray, body_to: np.ndarray, bound_at, dt: float,
                frames: int = PREROLL_FRAMES, settle: int = SETTLE_FRAMES) -> np.ndarray:
        """Dress the cloth into the first frame by simulation.

        The static dress of the first frame can have a leg through a skirt
        (the skirt is bound to the hips, the leg is forward): a collision
        cannot tell from there which side the cloth belongs on. Instead the
        cloth starts at rest on ``body_from`` (the bind pose, legs together:
        the items' own shape), turned and moved onto ``body_to`` by their
        best rigid fit, and the body moves to ``body_to`` over
        ``frames`` frames of ``dt`` (vertex positions blended with a
        smoothstep in time), the cloth pushed along; then ``settle`` more
        frames at ``body_to`` let it come to rest. The next :meth:`step`
        (the shot's first) starts it moving (:meth:`_start_moving`).

        Parameters
        ----------
        body_from, body_to : (N, 3) body points.
        bound_at : callable, body points (N, 3) -> bound item points (M, 3).
        dt : frame length (s).

        Returns
        -------
        (M, 3) item points on ``body_to``, the cloth simulated.
        """
        b_to = np.asarray(body_to, dtype=np.float64)
        # the bind pose turned and moved onto the first frame first: blending
        # vertex positions across a half turn would pass the body through itself
        _, rot, shift = similarity_fit(np.asarray(body_from, dtype=np.float64), b_to, scale=False)
        b_from = np.asarray(body_from, dtype=np.float64) @ rot + shift
        relaxed = bound_at(b_from)
        if self.rest_points is not None and self.n_free:
            # the cloth starts as its rest state (the static dress on the
            # bind pose), turned with the body
            relaxed = relaxed.copy()
            rows = self.hanging
            relaxed[rows] = self.rest_points[rows] @ rot + shift
        self.reset(b_from, relaxed)
        bound_to = bound_at(b_to)
        if self.n_free == 0:
            return bound_to
        for k in range(1, frames + 1):
            a = float(smoothstep(np.array(k / frames)))
            body = (1.0 - a) * b_from + a * b_to
            self.step(body, bound_at(body) if k < frames else bound_to, dt)
        for _ in range(settle):
            self.step(b_to, bound_to, dt)
        # the shot's own frames are timed from here on
        self.timings = {"frames": 0, "solve_s": 0.0, "solve_cpu_s": 0.0, "preroll_s": self.timings["solve_s"]}
        # the clip is already moving at its first frame: the first step gives
        # the settled cloth its attachment line's velocity
        self._launch = True
        return self._points(bound_to)

    def floors(self, rows: np.ndarray | None = None) -> np.ndarray:
        """(M, 6) the skin under each free vertex after the last step: the
        tangent plane of its nearest body vertex (the collision's own
        estimate; a point (3) and the unit normal (3)), as a floor the
        passes after the cloth must not move it behind
        (:class:`strain_limit.StrainLimit`'s ``planes``). Shortening an
        edge over a calf, the strain limit took a free vertex of the long
        skirt 8 mm into it, the skin showing through (CMU walk, frame 0:
        the static foot triangle it guards against lay elsewhere). Zero rows
        (no floor) for the other vertices, the free ones outside ``rows``
        ((M,) bool; None: all) and those with no body vertex near."""
        m = len(self.weights)
        out = np.zeros((m, 6))
        if self.n_free == 0:
            return out
        j = self.hint[:self.n_free]
        keep = j >= 0
        if rows is not None:
            keep &= np.asarray(rows, dtype=bool)[self.free]
        ok = np.flatnonzero(keep)
        out[self.free[ok], :3] = self.b0[j[ok]]
        out[self.free[ok], 3:] = self.n0[j[ok]]
        return out

    def _points(self, bound: np.ndarray) -> np.ndarray:
        """(M, 3): ``bound`` with the free vertices at the cloth's positions."""
        out = np.array(bound, dtype=np.float64, order="C", copy=True)
        out[self.free] = self.x[:self.n_free]
        return out

    def _start_moving(self, body1: np.ndarray, targets1: np.ndarray, dt: float) -> None:
        """The velocity the cloth starts the shot with: after :meth:`preroll`
        it hangs at rest on the first frame while the clip is already
        moving. Each connected piece (a skirt, a ponytail) takes the mean
        velocity of its attachment line (its bound particles: ``targets1``
        against the last targets) over this step; a piece with none the
        body's mean velocity (``body1``, the collider's vertices, against
        the last). A translation: the line's turn, carried to a hem 70 cm
        below the hips, threw the hem into the legs (module docstring)."""
        self._launch = False
        inv_dt = 1.0 / max(float(dt), 1e-9)
        for c in np.unique(self.piece[:self.n_free]):
            members = np.flatnonzero(self.piece == c)
            free, line = members[members < self.n_free], members[members >= self.n_free]
            move = targets1[line] - self.t0[line] if len(line) else body1 - self.b0
            self.v[free] = np.mean(move, axis=0) * inv_dt

    def step(self, body_points: np.ndarray, bound_points: np.ndarray, dt: float) -> np.ndarray:
        """Advance by one frame.

        Parameters
        ----------
        body_points : (N, 3) the body at this frame.
        bound_points : (M, 3) all item points as the binding places them at
            this frame (the targets).
        dt : seconds since the previous frame.

        Returns
        -------
        (M, 3) item points: ``bound_points`` with the free vertices simulated.
        """
        bound = np.asarray(bound_points, dtype=np.float64)
        if self.n_free == 0:
            return bound
        t_start, c_start = time.perf_counter(), time.process_time()
        b1 = np.ascontiguousarray(np.asarray(body_points, dtype=np.float64)[self.collider])
        n1 = self._body_normals(body_points)
        t1 = np.ascontiguousarray(bound[self.particles])
        move = float(np.sqrt(np.max(np.einsum("ij,ij->i", b1 - self.b0, b1 - self.b0))))
        # every sample near the body: its nearest body vertex on last frame's
        # body; between these searches the kernel's walk follows it
        self._since += float(dt)
        if self._since >= SEEK_INTERVAL - 1e-9:
            # the samples that may touch the body (all of them now and then):
            # their nearest body vertex on last frame's body, within what the
            # body can travel until the next search
            self._since = 0.0
            radius = self.reach + self.gap + move * max(1.0, SEEK_INTERVAL / max(float(dt), 1e-9))
            if self._frame % RESEED_EVERY == 0:
                self._seek(radius)
            else:
                self._seek(radius, np.flatnonzero(self.clear < radius))
            self._frame += 1
        if self._launch:
            self._start_moving(b1, t1, dt)
        cloth_frame(ClothState(self.x, self.v, self.inv_m, self.att_alpha), ClothTargets(self.t0, t1),
                    ClothEdges(self.edges, self.rest, self.colour_ptr), self.tethers,
                    ClothSamples(self.samples, self.sample_ptr, self.hint, self.margin, self.clear, self.layer_row,
                                 self.allow, self.top),
                    ClothBody(self.b0, b1, self.n0, n1, *self.adjacency, self.layer, move, self.gap),
                    ClothParams(self.gravity, self.damping, self.friction, self.stretch_alpha, self.compress_alpha,
                                float(dt), self.substeps(dt), self.iterations),
                    compiled=self.compiled, scratch=self._scratch)
        self.b0, self.n0, self.t0 = b1, n1, t1
        self.grid.update(b1)
        self.timings["frames"] += 1
        self.timings["solve_s"] += time.perf_counter() - t_start
        self.timings["solve_cpu_s"] += time.process_time() - c_start
        return self._points(bound)
