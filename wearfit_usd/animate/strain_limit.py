"""Strain limiting of the animated items: no edge stretched beyond what the
body under it allows.

Fabric stretches little; skin a lot (the front of a bending knee 1.5x).
An item edge that follows the body may stretch as the skin under it does,
and an offset surface over a bending joint a little more: the body's own
stretch range of :func:`dress.body_stretch.stretch_range`, from the static
dress to this frame, ``hi_e`` (its top end) for edge ``e``. Beyond that
the edge is torn, by whatever moved its ends apart: the penetration
guard pushing one end out of a crossing limb and not the other, the
binding of two neighbours to different body parts (an armpit), the cloth's
collisions. This is the deformation constraint of Provot (1995), "Deformation
constraints in a mass-spring model to describe rigid cloth behavior", as a
projection after the frame's other passes:

    L_e = |x_b - x_a| > limit * hi_e * L0_e  ->
    x_a += s_a (L_e - limit hi_e L0_e) u_e,   x_b -= s_b (...) u_e

with ``u_e`` the unit edge direction, ``s_a + s_b = 1`` by the ends'
inverse masses (a vertex the guard pushed this frame weighs ``HEAVY`` times
as much: it is where it must be), ``iterations`` passes, and no move taking a
vertex closer than ``MARGIN`` to the skin under it (an edge over a bending
joint shortens along its chord, into the body), nor behind a plane the
caller gives for this frame (``planes``: a skirt's free vertices, the skin
the cloth found under them, :meth:`cloth.ClothSolver.floors`). A vertex more
than ``FOOT_LOST`` behind the skin under it is not over that
skin any more (hair or a skirt swung round it; the penetration pass has put
it outside the body): its moves are not cut there, nor is it a vertex at the
skin. Before, every inward move of such a vertex was cut whole, its edges
could not shorten, and the passes piled their excess onto its neighbours'
(session 34, every-clip sweep with ``ref_male`` on ``body_male_muscular_heavy``
added, same run: figures over issue 17's limits 55 -> 46 with 2 mm; see
``docs/motion_loose_parts.md``). Only edges longer than
``limit`` times their static length are examined (the skin's stretch is
then computed for them alone), so a frame without tears costs one pass of
edge lengths.

A pass is Gauss-Seidel: edge by edge in ascending index order (the mesh's
own, neighbours near each other), descending on the next pass, each edge
seeing its neighbours' moves of the same pass, so one pass carries a pull
along a whole strip (halving it at each edge) where the mean of a vertex's
corrections (Jacobi, sessions 26-32) carried it one edge per pass. Edges
with an end on a plane, or within ``NEAR_SKIN`` of the skin under it when
the call starts, keep the Jacobi mean, taken after the sweep: a move cut
at a floor or the skin slides the vertex along it, and such slides made
one edge at a time ratchet (``ref_male`` on ``body_male_muscular_heavy``,
CMU walk: the trousers' inner thighs, 25 mm edges on the skin opened to
55 mm, stretch max 3.86, p99 1.14). An edge is over only by more than
``kernels.strain.OVER_SLACK`` (relative), so a pass with nothing left to
do ends the frame's passes. Every-clip sweep, same tree otherwise (session
33): figures over issue 17's limits 50 -> 44 (``male_casualsuit01`` 6 ->
2, ``ponytail01`` 14 -> 13, ``female_casualsuit02`` 6 -> 5,
``female_casualsuit01`` 1 -> 0, the long skirt 23 -> 24); Gauss-Seidel at
the skin too: 41, but the muscular walk above. The motion benchmark (60
frames): ``male_casualsuit01`` on ``body_male_muscular_heavy`` walk stretch
max 1.92 -> 1.84, arms held high 1.60 -> 1.54. The compiled passes' time in
the CMU walk (``ref_male``'s 28,258 item edges on ``body_male_heavy``, 80
frames, 101 calls): 0.22-0.23 s (Jacobi 0.10 s; the whole shot 4.4-4.5 s
against 4.2-4.6 s; two runs each). The numpy twin follows the same order as waves
of edges that share no vertex (:func:`kernels.strain.wavefront_levels`):
140 ms a call (Jacobi 25 ms). Colour order instead (a colour of edges with
no shared vertex at a time): 46 over; the mesh's order gets farther per
pass. 32 passes instead of 16 (Gauss-Seidel at the skin too): 41 -> 39.

Measured (every-clip sweep, 8 CMU clips, same tree otherwise; means over
the clips): stretch p99 of the long skirt 1.32 -> 1.15,
``female_casualsuit02`` 1.45 -> 1.18, ``male_casualsuit01`` 1.29 -> 1.15;
new penetrations 0.25 -> 0.41 %, 0.68 -> 0.85 %, 0.31 -> 0.35 % (0.60,
0.96, 0.37 % when moves could go into the body). The compiled pass
(:func:`kernels.strain.strain_frame`; after its first pass it looks only at
the edges of the vertices it moved) takes 2.2 ms for a frame's first call
on ``ref_male``'s 28,258 item edges (the allowed lengths computed) and
0.75-0.8 ms for each round after the weld (CMU walk, medians, session 27),
this numpy twin 17 ms (8 passes).
16 passes instead of 8 (every-clip sweep, same tree otherwise): figures
over issue 17's limits 151 -> 137, the worst of all clips' stretch p99 /
max of the long skirt 1.66 / 2.57 -> 1.59 / 1.98, ``male_casualsuit01``
1.25 / 3.45 -> 1.21 / 2.98, ``ponytail01`` 1.78 / 6.59 -> 1.65 / 5.90;
new penetrations of the long skirt's worst frame 3.37 -> 4.49 % (mean
0.41 -> 0.47 %); the walk's time unchanged (most frames stop early). On
the demo's suit and coat the armpits' stretch max rose 3.22-5.38 ->
3.59-5.92 (p99 down): edges that can only shorten into the body keep
the excess their converged neighbours hand them.

The weld of sub-millimetre edges (:class:`short_edges.ShortEdgeWeld`) runs
inside every pass too (``weld``): its groups clamped to their rest reach
after each pass's moves, the members it moved joining the next pass. In a
pass a weld group's short edge is one vote among its ends' edges: where
panels meet at a seam (``female_casualsuit02`` on ``body_female_heavy``, CMU
walk frame 16: 0.7-0.9 mm welds beside 2.5-3 mm seam edges) the frame's
first 16 passes opened the welds to 2.2-2.9x and pulled the seam edges
beside them from 1.3x to 2.0x, and every weld after a round undid the first
half of that alone. Every-clip sweep, same tree otherwise (session 31):
figures over issue 17's limits 56 -> 54; stretch max over the clips (mean)
``female_casualsuit02`` 2.31 -> 2.01 (walk 2.45 -> 1.87, run 3.02 -> 2.51,
punch 1.81 -> 1.49), ``ponytail01`` 2.24 -> 2.06 (jump 2.08 -> 1.74, arms
held high 2.61 -> 2.00; its start-walk-stop 1.84 -> 2.11), the long skirt
unchanged. Its cost: the CMU walk's strain-and-guard time 0.91-0.93 ->
0.97-0.98 s (``ref_male`` on ``body_male_heavy``), 1.02-1.03 -> 1.05-1.07 s
(``ref_female`` on ``body_female_thin``; two interleaved runs each). Pooling
a group's moves instead (the group moving as one) gained less or lost (the
run 3.02 -> 2.76; session 30: the ponytail's hair tie 1.22 -> 2.85).

Arrays are numpy; metres.
"""
from __future__ import annotations

import numpy as np

from ..dress.body_stretch import local_triangles, offset_factor, principal_stretches, triangle_grams
from ..geometry.closest import SurfaceQuery, VertexNormals, point_and_normal
from ..kernels import (
    HAVE_NUMBA,
    StrainRest,
    clear_caps,
    edge_incidence,
    new_caps,
    strain_frame,
    wavefront_levels,
    weld_groups,
)
from ..kernels.strain import OVER_SLACK, REACH_SLACK

LIMIT = 1.1        # x the body's own stretch an edge may reach
ITERATIONS = 16    # passes per frame (at most)
HEAVY = 5.0        # mass of a vertex the guard pushed, against 1
#: passes of a second round after the weld of sub-millimetre edges
#: (:class:`short_edges.ShortEdgeWeld`), which runs after the strain limit:
#: clamping a group's members to their rest distance from its centre moves
#: them along their other edges, and those were stretched again
#: (``ponytail01``'s 1.8 mm edge at 2.2 mm after the limit, 3.5 mm after the
#: weld; CMU walk, frame 4). ``animate`` limits again with this many passes,
#: then welds again. Every-clip sweep, same tree otherwise, 0 -> 8 -> 16
#: passes: figures over issue 17's limits 132 -> 122 -> 117; the worst of all
#: clips' stretch max ponytail01 4.20 -> 3.38 -> 3.38, bob01 2.04 -> 1.79 ->
#: 1.63, female_casualsuit02 4.37 -> 3.93 -> 3.81, male_casualsuit01 2.91 ->
#: 2.61 -> 2.38, the long skirt 2.57 -> 2.24 -> 2.00; the long skirt's new
#: penetrations in the Daz walk 0.84 -> 1.40 % (8), in the CMU walk 0.70 ->
#: 1.40 % (16)
WELD_ROUND_PASSES = 16
#: rounds of the limit (``WELD_ROUND_PASSES`` passes) and the weld after the
#: first weld. 1 -> 2 rounds (every-clip sweep, same tree otherwise): figures
#: over the limits 117 -> 108 (9 under, none over); the worst of all clips'
#: stretch max ponytail01 3.38 -> 3.06, female_casualsuit02 3.81 -> 3.51,
#: male_casualsuit01 2.38 -> 2.13, bob01 1.63 -> 1.46; the long skirt's worst
#: new penetrations 13.5 -> 13.9 % (over before and after). 128 passes on the
#: first dress instead (relax_first_dress) gave 118, mixed. 2 -> 3 rounds
#: (every-clip sweep, session 26, same tree otherwise): figures over 81 -> 78
#: (3 under, none over); stretch max of every suit and hair on every clip
#: lower (ponytail01 3.06 -> 2.86, female_casualsuit02 3.51 -> 3.28,
#: male_casualsuit01 2.13 -> 1.98); new penetrations at most 0.04 points up
#: (the long skirt's arms held high 1.40 -> 1.26 %).
#: A last limit pass after the weld instead re-opened the weld's groups
#: (bob01's stretch max 1.24 -> 3.69). Its price: 1.1-2.4 ms a frame (the
#: ref_male walk's strain-and-guard time 0.90-0.97 -> 0.99-1.09 s, 79 frames).
#: With the weld inside every pass (session 31; same tree otherwise) 3 -> 4
#: rounds: figures over 54 -> 52 (female_casualsuit02 8 -> 6; every suit's
#: stretch max lower or equal but the long skirt's start-walk-stop 3.40 ->
#: 3.55, cloth), 0.4-2.4 ms a frame (the CMU walk, 79 frames: 0.86-0.91 ->
#: 0.94-0.95 s ref_male, 0.99-1.02 -> 1.10-1.18 s ref_female_longskirt);
#: 6 rounds: 50 over, but 2.8-5.7 ms a frame and the long skirt's jump over
#: in new penetrations (0.98 -> 1.12 %); 0 or 1 round: 83 and 68 over.
WELD_ROUNDS = 4
MARGIN = 0.001     # m: no move takes a vertex closer to the skin under it than this
#: m: a vertex closer than this to the skin under it when a call starts takes
#: the Jacobi mean of its edges' corrections, as one on a cloth floor does (its
#: moves one edge at a time are cut at the skin and slide along it: see the
#: module docstring)
NEAR_SKIN = 0.0015
#: m: a vertex farther than this behind the skin under it (its static
#: closest triangle, on this body) is not over that skin any more: hair or a
#: skirt swung round (a ponytail in a pirouette 10 cm behind the plane of
#: the neck it hung over at rest; the penetration pass has already put it
#: outside the body), so no move of it is cut at that plane and it is not a
#: vertex at the skin (which takes the Jacobi mean). Before, every inward
#: move of such a vertex was cut whole, its edges could not shorten, and the
#: passes piled their excess onto its neighbours' edges. Every-clip sweep
#: (four pairs), same tree otherwise: figures over issue 17's limits 55 ->
#: 46 with 2 mm (1 mm: 46, 3 mm: 47, 5 mm: 50, 15 mm: 50); ``ponytail01``
#: start-walk-stop stretch max 2.12 -> 1.18, the long skirt's run new
#: penetrations 2.10 -> 0.84 % and coverage loss 14.13 -> 8.88 %
FOOT_LOST = 0.002


class StrainLimit:
    """``limit(body (N, 3), points (M, 3), pushed=None) -> points`` (in
    place): item edges longer than ``limit`` x the body's own stretch under
    them shortened (module docstring).

    Parameters
    ----------
    items0 : (M, 3) the items dressed statically (frame 0).
    edges : (E, 2) int, the items' edges.
    body_faces : (T, 3) int; body0 : (N, 3) the body of ``items0``.
    movable : (M,) bool, the vertices it may move (not the rigid parts).
    limit, iterations : see the module docstring.
    compiled : the numba kernel (:func:`kernels.strain.strain_frame`;
        default: when installed) or its numpy twin (this class's own passes).
    weld : :class:`short_edges.ShortEdgeWeld`, optional: the weld of the
        items' sub-millimetre edges, applied after every pass (its groups
        clamped to their rest reach; a member it moves joins the next
        pass). Else a pass can open a weld group (its short edges carry one
        vote among a vertex's edges) that the weld closes after the limit,
        stretching the group's other edges again (module docstring).
    """

    def __init__(self, items0: np.ndarray, edges: np.ndarray, body_faces: np.ndarray, body0: np.ndarray,
                 movable: np.ndarray, limit: float = LIMIT, iterations: int = ITERATIONS,
                 compiled: bool | None = None, weld=None):
        q = np.ascontiguousarray(items0, dtype=np.float64)
        e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        self.faces = np.ascontiguousarray(body_faces, dtype=np.int64)
        self.body0 = np.ascontiguousarray(body0, dtype=np.float64)
        movable = np.asarray(movable, dtype=bool)
        if q.ndim != 2 or q.shape[1] != 3 or movable.shape != (len(q),):
            raise ValueError(f"items0 {q.shape} and movable {movable.shape} do not match")
        if len(e) and (e.min() < 0 or e.max() >= len(q)):
            raise ValueError(f"edges index {len(q)} item points out of range")
        if limit < 1.0 or iterations < 1:
            raise ValueError(f"limit {limit} (>= 1), iterations {iterations} (>= 1)")
        self.limit, self.iterations = float(limit), int(iterations)
        # the edges it may shorten: one end movable, of nonzero length
        len0 = np.linalg.norm(q[e[:, 1]] - q[e[:, 0]], axis=1)
        keep = (movable[e[:, 0]] | movable[e[:, 1]]) & (len0 > 1e-9)
        self.edges, self.len0 = e[keep], len0[keep]
        self.inv_mass = movable.astype(np.float64)
        foot = SurfaceQuery(self.faces, self.body0).closest(q)
        self.foot_tri, self.foot_bary = foot["triangle"], foot["bary"]
        self.clearance0 = foot["distance"]
        # the skin under each vertex, as the motion measures take it
        self.triangles = local_triangles(self.body0, self.faces, q, self.foot_tri)
        self._vn = VertexNormals(self.faces, len(self.body0))
        self._normals0 = self._vn(self.body0)
        self.stats = {"frames": 0, "edges_limited": 0}
        self._caps = self._caps_body = self._caps_normals = None  # the compiled pass's, on the last body
        self._no_planes = None  # the compiled pass's zero floors (none), kept
        self.compiled = HAVE_NUMBA if compiled is None else bool(compiled and HAVE_NUMBA)
        # vertex -> edge incidence (CSR rows: item vertices), the passes' active edges in both paths
        inc_ptr, inc_edge = edge_incidence(self.edges, len(q))
        self.weld = weld if weld is not None and len(weld) else None
        if self.weld is not None and self.weld.rows.max() >= len(q):
            raise ValueError(f"the weld's groups reach vertex {self.weld.rows.max()}, the items have {len(q)}")
        none = np.zeros(0, dtype=np.int64)
        groups = weld_groups(none, none, np.zeros(0)) if self.weld is None else \
            weld_groups(self.weld.rows, self.weld.group, self.weld.reach)
        if not self.compiled:
            # the passes' edge order as waves of edges that share no vertex
            self._waves = wavefront_levels(self.edges, len(q))
            self._inc = (inc_ptr, inc_edge)
        f = self.faces
        gram = triangle_grams(self.body0, f)
        foot0, normal0 = point_and_normal(self.body0, self._normals0, f, self.foot_tri, self.foot_bary)
        self._rest = StrainRest(np.ascontiguousarray(self.edges), np.ascontiguousarray(self.len0),
                                np.ascontiguousarray(self.triangles), f, np.ascontiguousarray(gram),
                                np.ascontiguousarray(self.foot_tri, dtype=np.int64),
                                np.ascontiguousarray(self.foot_bary, dtype=np.float64), foot0, normal0,
                                np.ascontiguousarray(self.clearance0, dtype=np.float64), inc_ptr, inc_edge,
                                *groups)

    def allowed(self, body: np.ndarray, idx: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(len(idx),) the longest each edge ``self.edges[idx]`` may be on
        this body (N, 3): ``limit`` x its static length x the body's own
        stretch under it (:func:`dress.body_stretch.stretch_range`'s top).
        ``normals``: the body's vertex normals (N, 3) if already computed."""
        e = self.edges[idx]
        ends = np.unique(e)
        tris = np.unique(self.triangles[ends])
        _, hi_t = principal_stretches(self.body0, body, self.faces[tris])
        hi_of = np.zeros(len(self.faces))
        hi_of[tris] = hi_t
        hi_v = hi_of[self.triangles[e]].max(axis=(1, 2))
        if normals is None:
            normals = self._vn(body)
        fac = offset_factor(self.body0, body, self.faces, self.foot_tri, self.foot_bary, self.clearance0, e,
                            self.len0[idx], normals=(self._normals0, normals))
        return self.limit * self.len0[idx] * hi_v * np.maximum(fac, 1.0)

    def _skin_under(self, body: np.ndarray, rows: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The skin under vertices ``rows`` at ``p`` (R, 3) on ``body``: its
        unit normal (R, 3) and their height over it (R,), the skin being a
        vertex's static closest triangle on this body (its point at the same
        barycentrics, that triangle's normal)."""
        f = self.faces[self.foot_tri[rows]]
        v = body[f]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        foot = np.einsum("rc,rci->ri", self.foot_bary[rows], v)
        return n, np.einsum("ri,ri->r", p - foot, n)

    def _not_inward(self, body: np.ndarray, rows: np.ndarray, p: np.ndarray, step: np.ndarray,
                    planes: np.ndarray | None = None) -> np.ndarray:
        """``step`` (R, 3) of vertices ``rows`` at ``p`` (R, 3), with its
        part into the body cut to what keeps them ``MARGIN`` outside: the
        skin under a vertex is its static closest triangle on this body
        (its point at the same barycentrics, that triangle's normal). A
        strain-limited edge over a bending joint shortens along its chord,
        into the body; the penetration pass has already run."""
        n, clear = self._skin_under(body, rows, p)
        inward = -np.einsum("ri,ri->r", step, n)
        room = np.maximum(clear - MARGIN, 0.0)
        # no cut where that skin is not under the vertex any more (FOOT_LOST)
        cut = np.where(clear > -FOOT_LOST, np.maximum(inward - room, 0.0), 0.0)
        step = step + cut[:, None] * n
        if planes is not None:
            # and not behind this frame's plane of the vertex (zero normal: none)
            g = planes[rows]
            clear = np.einsum("ri,ri->r", p - g[:, :3], g[:, 3:])
            inward = -np.einsum("ri,ri->r", step, g[:, 3:])
            cut = np.maximum(inward - np.maximum(clear, 0.0), 0.0)
            step = step + cut[:, None] * g[:, 3:]
        return step

    def __call__(self, body: np.ndarray, points: np.ndarray, pushed: np.ndarray | None = None,
                 iterations: int | None = None, planes: np.ndarray | None = None) -> np.ndarray:
        """``iterations``: this call's passes (default ``self.iterations``;
        a further round in the same frame, see :data:`WELD_ROUND_PASSES`).
        ``planes`` (M, 6): a further floor per vertex for this call, a point
        and a unit normal no move may take it behind (zero normal: none;
        the cloth's skin under its free vertices, :meth:`cloth.ClothSolver.floors`)."""
        its = self.iterations if iterations is None else int(iterations)
        if iterations is None:
            self.stats["frames"] += 1
        e = self.edges
        if len(e) == 0:
            return points
        body = np.ascontiguousarray(body, dtype=np.float64)
        if self.compiled:
            caps, normals = self._caps_on(body)
            w = self.inv_mass.copy()
            if pushed is not None:
                w[np.asarray(pushed, dtype=bool)] /= HEAVY
            work = points if points.flags.c_contiguous and points.dtype == np.float64 else \
                np.ascontiguousarray(points, dtype=np.float64)
            if planes is None:
                if self._no_planes is None or len(self._no_planes) != len(work):
                    self._no_planes = np.zeros((len(work), 6))  # no floors: made once, not per call
                planes = self._no_planes
            self.stats["edges_limited"] += strain_frame(self._rest, body, normals, work, w, self.limit, its, MARGIN,
                                                        caps, np.ascontiguousarray(planes, dtype=np.float64),
                                                        NEAR_SKIN, FOOT_LOST)
            if work is not points:
                points[:] = work
            return points
        n = len(points)
        cap = np.full(len(e), np.inf)   # this frame's allowed lengths, computed where needed
        known = np.zeros(len(e), dtype=bool)
        self._twin_normals = None
        limited = np.zeros(len(e), dtype=bool)
        active = np.arange(len(e))      # the edges that can be over: all, then those touching a moved vertex
        w = self.inv_mass.copy()
        if pushed is not None:
            w[np.asarray(pushed, dtype=bool)] /= HEAVY
        # the vertices that take the Jacobi mean: on a plane, or at the skin
        clear = self._skin_under(body, np.arange(n), points)[1]
        on_plane = (clear < NEAR_SKIN) & (clear > -FOOT_LOST)
        if planes is not None:
            on_plane |= (np.asarray(planes)[:, 3:] != 0.0).any(axis=1)
        for it in range(its):
            jac = on_plane[e[active, 0]] | on_plane[e[active, 1]]
            gs, jac = active[~jac], active[jac]
            self._over(body, points, active, cap, known, first=it == 0)  # the caps of the edges over now, at once
            # Gauss-Seidel over the edges off the planes, in ascending edge
            # order on even passes and descending on odd ones, as waves of
            # edges that share no vertex (kernels.strain.wavefront_levels);
            # an edge at a vertex moved before its turn joins the pass
            wave = self._waves[it % 2]
            pending = np.zeros(len(e), dtype=bool)
            pending[gs] = True
            jac_set = np.zeros(len(e), dtype=bool)
            jac_set[jac] = True
            queue = gs
            moved = []
            while len(queue):
                wq = wave[queue]
                now = wq.min()
                idx = queue[wq == now]
                queue = queue[wq != now]
                on, d, ln = self._over(body, points, idx, cap, known)
                if len(on) == 0:
                    continue
                limited[on] = True
                # both ends at once: no two edges of a wave share a vertex
                ends, moves, ok = self._pulls(on, d, ln, cap, w)
                rows, step = ends[ok], moves[ok]
                points[rows] += self._not_inward(body, rows, points[rows], step, planes)
                moved.append(rows)
                later = self._touching(rows)
                later = later[(wave[later] > now) & ~pending[later] & ~jac_set[later]]
                floor = on_plane[e[later, 0]] | on_plane[e[later, 1]]
                jac_set[later[floor]] = True
                later = later[~floor]
                pending[later] = True
                queue = np.concatenate([queue, later])
            jac = np.flatnonzero(jac_set)
            # the edges with an end on a plane: Jacobi, on the points the sweep left
            on, d, lo = self._over(body, points, jac, cap, known)
            if len(on):
                limited[on] = True
                ends, moves, ok = self._pulls(on, d, lo, cap, w)
                count = np.bincount(ends, weights=ok.astype(np.float64), minlength=n)
                rows = np.flatnonzero(count > 0)
                step = np.stack([np.bincount(ends, weights=moves[:, i], minlength=n)[rows] for i in range(3)], axis=1)
                step /= count[rows, None]
                points[rows] += self._not_inward(body, rows, points[rows], step, planes)
                moved.append(rows)
            elif not moved:
                break
            moved = np.unique(np.concatenate(moved))
            if self.weld is not None:
                moved = np.union1d(moved, self._weld_clamp(points))
            active = self._touching(moved)
        self.stats["edges_limited"] += int(limited.sum())
        return points

    def _pulls(self, on: np.ndarray, d: np.ndarray, ln: np.ndarray, cap: np.ndarray,
               w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The moves of the ends of edges ``on`` (k,), over their cap, with
        vectors ``d`` (k, 3) and lengths ``ln`` (k,), shared by the ends'
        inverse masses ``w``: (end rows (2k,): every a then every b, their
        moves (2k, 3), whether each end may move (2k,) bool)."""
        ce = self.edges[on]
        wa, wb = w[ce[:, 0]], w[ce[:, 1]]
        share_a = wa / np.maximum(wa + wb, 1e-300)
        c = ((ln - cap[on]) / np.maximum(ln, 1e-300))[:, None] * d
        return (np.concatenate([ce[:, 0], ce[:, 1]]),
                np.concatenate([c * share_a[:, None], -c * (1.0 - share_a)[:, None]]),
                np.concatenate([wa > 0, wb > 0]))

    def _over(self, body: np.ndarray, points: np.ndarray, idx: np.ndarray, cap: np.ndarray, known: np.ndarray,
              first: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The numpy passes' test of edges ``idx`` on ``points``: (the edges
        over their allowed length, their vectors (k, 3) and lengths (k,)).
        Allowed lengths are computed into ``cap`` where not ``known`` yet
        (on the ``first`` pass with the edges round them: the later passes'
        candidates in one call)."""
        ea = self.edges[idx]
        d = points[ea[:, 1]] - points[ea[:, 0]]
        ln = np.sqrt(np.einsum("ij,ij->i", d, d))
        cand = ln > self.limit * self.len0[idx]
        new = idx[cand & ~known[idx]]
        if len(new):
            if self._twin_normals is None:
                self._twin_normals = self._vn(body)
            if first:
                new = self._with_neighbours(new)
                new = new[~known[new]]
            cap[new] = self.allowed(body, new, self._twin_normals)
            known[new] = True
        over = cand & (ln > cap[idx] * (1.0 + OVER_SLACK))
        return idx[over], d[over], ln[over]

    def _weld_clamp(self, points: np.ndarray) -> np.ndarray:
        """The weld's groups back within their rest reach about their centre
        (as :class:`short_edges.ShortEdgeWeld` does), in place on points
        (M, 3); members at their reach to ``kernels.strain.REACH_SLACK`` left. Returns the
        rows it moved."""
        rows, group, reach = self.weld.rows, self.weld.group, self.weld.reach
        n_g = self.weld.n_groups
        size = np.bincount(group, minlength=n_g)
        p = points[rows]
        centre = np.stack([np.bincount(group, weights=p[:, i], minlength=n_g) for i in range(3)], axis=1)
        centre = (centre * (1.0 / size)[:, None])[group]
        d = p - centre
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        out = r > reach * (1.0 + REACH_SLACK)
        points[rows[out]] = centre[out] + d[out] * (reach[out] / r[out])[:, None]
        return rows[out]

    def _caps_on(self, body: np.ndarray):
        """The compiled pass's allowed lengths (:class:`kernels.strain.StrainCaps`)
        and the vertex normals on ``body`` (N, 3): kept from the last call
        when its body was the same (a frame's rounds after the weld: the
        caps cost most of a call), else cleared for this one."""
        if self._caps is None:
            self._caps = new_caps(len(self.edges), len(self._rest.clear0), len(self.faces))
        elif self._caps_body is not None and np.array_equal(self._caps_body, body):
            return self._caps, self._caps_normals
        else:
            clear_caps(self._caps)
        self._caps_body = body.copy()
        self._caps_normals = self._vn(body)
        return self._caps, self._caps_normals

    def _touching(self, rows: np.ndarray) -> np.ndarray:
        """The edges (indices) with an end in ``rows``, ascending."""
        ptr, inc = self._inc
        start, count = ptr[rows], ptr[rows + 1] - ptr[rows]
        # the CSR rows' entries gathered: each row's start plus 0..count-1
        at = np.repeat(start - np.cumsum(count) + count, count) + np.arange(count.sum())
        return np.unique(inc[at])

    def _with_neighbours(self, idx: np.ndarray) -> np.ndarray:
        """Edges ``idx`` and every edge sharing a vertex with one of them."""
        return np.union1d(idx, self._touching(np.unique(self.edges[idx])))
