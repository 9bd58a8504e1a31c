"""Per-frame penetration pass of an animation: item vertices that sink into
the moving body are pushed back out, coherently over time.

Built once on the dressed frame (:class:`PenetrationGuard`), applied every
frame to the evaluated item points. Arrays are numpy; lengths in metres.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..geometry.closest import SurfaceQuery, VertexNormals
from ..geometry.mesh import edge_length_percentile, short_edge_weights
from ..kernels import HAVE_NUMBA, GuardBody, GuardState, RadiusGrid, face_normal_sums, guard_estimate, guard_frame


class PenetrationGuard:
    """Per-frame push-out of item vertices that sink into the moving body.

    Built once on the dressed frame: every item vertex keeps its clearance
    ``c0`` (signed distance to the body at frame 0) and its 4 nearest body
    triangles. Each frame, the nearest body vertex within ``radius`` (a
    uniform grid rebuilt per frame) and its normal give a cheap clearance
    estimate; the suspects (estimate 2 mm below its frame-0 value or under
    the margin, or still pushed) get the exact closest point among their
    frame-0 triangles and the triangles around their nearest vertex now (so a
    limb pressing into the torso is seen), and are moved out along the
    surface normal to their clearance; the pushed point is checked the same
    way, and one that is still within the margin (pushed into another body
    part, as in an armpit) gets a second push from there. Temporal coherence: a push decays
    geometrically (``decay`` per frame) instead of switching off, so vertices
    never pop; a decaying vertex is tested again only when its clearance
    estimate (push included) drops.

    With numba (``compiled``, the default when it is installed) a frame is
    one compiled pass over the item vertices that also starts each nearest
    vertex search from last frame's answer; the numpy path gives the same
    numbers.

    With ``item_neighbours`` (M, M) sparse, the guarded items' vertex
    adjacency (a dress plan's ``mesh.neighbours``), every frame's pushes are
    spread over the item (:meth:`_smoothed`): pushed alone, a
    vertex stood out of its neighbours in a spike and the edges round it
    tore (the guard alone took the hot pants and top of
    ref_female_longskirt walking on body_female_heavy from stretch p99
    1.75x to 2.21x). A neighbour over an edge much shorter than the
    vertex's others weighs more (:func:`geometry.mesh.short_edge_weights`,
    from ``item_points0``): two vertices 0.6 mm apart at the hot pants'
    waist, pushed 30 and 6 mm out of an arm crossing the hip, had averaged
    their pushes with their wider neighbours alike and stood 23 mm apart.

    With ``max_clearance`` the clearance a pushed vertex gets back is capped:
    ``min(c0, max_clearance)``. The guard keeps items out of the body, not
    their volume away from it: a vertex deep in a bulk of hair (frame-0
    clearance 4-6 cm at the nape) was pushed back to that distance from
    whatever surface its few candidate triangles offered, and when the head
    tilted back that was the skull's underside, so the push went down into
    the neck (the mannequin's arms-held-high dance: the ponytail's median
    push 29 mm, most of it into the body).

    With ``check_pushes`` (the default; :func:`animate.try_on.animate`
    uses it on every body) every frame's new pushes are checked against the
    whole body (:meth:`_checked`): the frame's few candidate triangles miss
    the closest one on coarse bodies and where body parts cross (an arm
    across the hip), and a push from a wrong surface tears the item.

    Guarded vertices with no body vertex within ``radius`` are not taken
    for far outside on that alone (:meth:`_deep`): a body part that comes
    through an item faster than the radius per frame leaves its vertices
    deeper than the radius, where the estimate sees nothing. The body
    vertex nearest to them within ``DEEP_REACH`` (or 1.5 x the body's long
    edges on a coarse body; searched from its last answer) tells which side
    of the skin they are on; those behind it get
    the whole-body check's exact distance and push. The whole-body check
    itself searches out to ``FAR_CHECK`` for the nearest triangle centre of
    a vertex that has none within its grid's radius.

    With ``also`` (M,) bool, those vertices are guarded too although they
    start inside the body (to the margin): a shot dressed in its first pose
    starts from a dress whose vertices can lie in the skin where the same
    items dressed on the bind pose do not (``female_casualsuit01`` in the
    pirouette: 27 of the 49 vertices the motion measures found newly inside
    at its worst frame were inside from the first frame, never guarded).

    body_faces (T, 3); body_points0 (N, 3) and item_points0 (M, 3) at the
    dressed frame; margin, radius and max_clearance in metres.
    """

    DROP = 0.002  # m: an estimated clearance this far under its frame-0 value makes a suspect
    FAR_CHECK = 0.5  # m: the whole-body check's second, wider search of the nearest triangle centroid
    DEEP_REACH = 0.1  # m: how far the search for a vertex deep inside the body looks for the nearest body vertex

    def __init__(self, body_faces: np.ndarray, body_points0: np.ndarray, item_points0: np.ndarray,
                 margin: float = 0.001, decay: float = 0.7, radius: float = 0.03,
                 compiled: bool | None = None, item_neighbours: sp.spmatrix | None = None,
                 max_clearance: float | None = None, check_pushes: bool = True,
                 also: np.ndarray | None = None):
        self.faces = np.ascontiguousarray(body_faces, dtype=np.int64)
        self._walk = None
        if item_neighbours is not None and item_neighbours.shape != (len(item_points0),) * 2:
            raise ValueError(f"item_neighbours is {item_neighbours.shape} for {len(item_points0)} item points")
        if item_neighbours is not None and item_neighbours.nnz:
            # neighbours over short edges weigh more (geometry.mesh.short_edge_weights)
            a = short_edge_weights(item_neighbours, item_points0)
            deg = np.asarray(a.sum(axis=1)).ravel()
            deg[deg <= 0] = 1.0
            self._walk = (sp.diags(1.0 / deg) @ a).tocsr()  # neighbour average
        self.radius = float(radius)
        self.compiled = HAVE_NUMBA if compiled is None else bool(compiled and HAVE_NUMBA)
        self.query = SurfaceQuery(self.faces, body_points0)
        self._grid = None
        if not self.compiled:  # vertex normal sums for the numpy estimate
            self._incidence = VertexNormals(self.faces, len(body_points0)).incidence
        else:
            self._edge_id = np.ascontiguousarray(self.query.edge_id, dtype=np.int64)
            self._ring = np.ascontiguousarray(self.query.ring, dtype=np.int64)
            # the faces of each edge in index order (-1 padded): edge normals on demand
            inc = self.query.edge_incidence.tocsr()
            inc.sort_indices()
            counts = np.diff(inc.indptr)
            self._edge_faces = np.full((inc.shape[0], max(int(counts.max()), 1)), -1, dtype=np.int64)
            self._edge_faces[np.repeat(np.arange(inc.shape[0]), counts),
                             np.arange(inc.nnz) - np.repeat(inc.indptr[:-1], counts)] = inc.indices
            self._vsum = np.empty((len(body_points0), 3))
            self._normals_of = None  # the body points the normal sums belong to
        c0 = self.query.signed_distance(item_points0)
        _, self.cand0 = self.query.centroid_tree.query(item_points0, k=4)
        self.approx0, _ = self.estimate(item_points0)
        self.outside0 = c0 > -margin           # only guard vertices that start outside
        if also is not None:
            self.outside0 |= np.asarray(also, dtype=bool).reshape(len(c0))
        # clearance to restore (>= margin, <= max_clearance)
        self.target = np.clip(c0, margin, None if max_clearance is None else max(float(max_clearance), margin))
        self.margin = margin
        self.decay = decay
        self.push = np.zeros(len(item_points0))   # current push amount (m)
        self.direction = np.zeros((len(item_points0), 3))
        self._hint = np.full(len(item_points0), -1, dtype=np.int64)  # last nearest body vertex
        self._deep_hint = np.full(len(item_points0), -1, dtype=np.int64)  # and within DEEP_REACH (_deep)
        self._deep_reach = None  # DEEP_REACH, or more on a coarse body (set on first use)
        self._cgrid = None  # the whole-body check's grid over the triangle centroids (built on first use)
        self.check_pushes = bool(check_pushes)

    def estimate(self, item_points: np.ndarray, grid: RadiusGrid | None = None):
        """Clearance estimate against the body at the last :meth:`update`:
        offset (M,) along the nearest body vertex's normal, +inf farther than
        ``radius`` from every body vertex (cannot sink this frame); and that
        nearest vertex (M,) (0 where far). ``grid``: a :class:`RadiusGrid`
        over the current body points, if the caller has one."""
        body = self.query.points
        if grid is None:
            grid = self._frame_grid()
        if self.compiled:
            self._sum_normals()
            q = np.ascontiguousarray(item_points, dtype=np.float64)
            est = np.empty(len(q))
            vi = np.empty(len(q), dtype=np.int64)
            guard_estimate(q, np.full(len(q), -1, dtype=np.int64), self._body(), grid.arrays, self.radius ** 2, est,
                           vi)
            return est, vi
        vi, _ = grid.nearest(item_points)
        far = vi < 0
        vi[far] = 0
        # unit-face-normal sums: cheaper than area weights, good enough here
        vn = self._incidence @ self.query.face_normal
        vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        est = np.einsum("ij,ij->i", item_points - body[vi], vn[vi])
        est[far] = np.inf
        return est, vi

    def update(self, body_points: np.ndarray) -> None:
        """Move the body to this frame's points (N, 3)."""
        self.query.update(body_points)

    def _frame_grid(self) -> RadiusGrid:
        """The radius grid over the current body points (rebuilt in place)."""
        if self._grid is None:
            self._grid = RadiusGrid(self.query.points, self.radius)
        elif self._grid.points is not self.query.points:
            self._grid.update(self.query.points)
        return self._grid

    def _sum_normals(self) -> None:
        """Per-vertex normal sums of the current body (compiled path), once
        per :meth:`update`."""
        if self._normals_of is not self.query.points:
            face_normal_sums(self.faces, self.query.face_normal, self._vsum)
            self._normals_of = self.query.points

    def _body(self) -> GuardBody:
        """The current body as the compiled kernels take it (after :meth:`_sum_normals`)."""
        q = self.query
        return GuardBody(q.points, self.faces, q.face_normal, self._edge_id, self._edge_faces, self._ring, self._vsum)

    def exact(self, idx: np.ndarray, item_points: np.ndarray, nearest_vertex: np.ndarray):
        """Exact signed distance (len(idx),) and closest-feature normal
        (len(idx), 3) of item_points[idx] among their frame-0 triangles and
        the triangles around ``nearest_vertex`` (len(idx),)."""
        return self._exact_at(idx, item_points[idx], nearest_vertex)

    def _exact_at(self, idx: np.ndarray, points: np.ndarray, nearest_vertex: np.ndarray):
        """:meth:`exact` for vertices idx placed at points (len(idx), 3)."""
        cand = np.concatenate([self.cand0[idx], self.query.ring[nearest_vertex]], axis=1)
        res = self.query.closest(points, candidates=cand, ring=False)
        return res["distance"], res["normal"]

    def apply(self, body_points: np.ndarray, item_points: np.ndarray):
        """Return (corrected item points (M, 3), number of suspects that were
        inside by more than the margin before correction)."""
        self.update(body_points)
        grid = self._frame_grid()
        # what a push that only decays keeps (the check looks at the others)
        before = (self.push * self.decay, self.direction.copy()) if self.check_pushes else None
        if self.compiled:
            self._sum_normals()
            q = np.ascontiguousarray(item_points, dtype=np.float64)
            out = np.empty_like(q)
            state = GuardState(self.cand0, self.approx0, self.outside0, self.target, self.push, self.direction,
                               self._hint)
            n_inside = guard_frame(q, state, self._body(), grid.arrays, self.radius ** 2, self.decay, self.margin,
                                   self.DROP, out)
            # the kernel's hint is -1 where no body vertex is within the radius
            out = self._deep(q, out, self.outside0 & (self._hint < 0))
            return self._smoothed(q, self._checked(q, out, before)), int(n_inside)
        push = self.push * self.decay
        pre = item_points + push[:, None] * self.direction
        approx, vi = self.estimate(pre, grid)
        # suspects: with the (decaying) push applied, the estimated clearance
        # dropped by 2 mm since frame 0 or is below the margin
        suspect = self.outside0 & ((approx < self.approx0 - self.DROP) | (approx < self.margin))
        idx = np.flatnonzero(suspect)
        n_inside = 0
        if len(idx):
            # the triangles around the vertex nearest to where the item vertex
            # is now (before any push): a limb pressing in is found there
            near, _ = grid.nearest(item_points[idx])
            near = np.where(near < 0, vi[idx], near)
            dist, n = self.exact(idx, item_points, near)
            n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            n_inside = int(np.sum(dist < -self.margin))
            need = np.where(dist < self.target[idx], self.target[idx] - dist, 0.0)
            push[idx] = np.maximum(need, push[idx])
            self.direction[idx] = n
            # the pushed points checked the same way: one still within the
            # margin (pushed into another body part, or a wrong first normal)
            # is pushed again from there, both pushes combined into one
            pushed = push[idx] >= 1e-5
            sel = idx[pushed]
            if len(sel):
                q = item_points[sel] + push[sel, None] * self.direction[sel]
                near2, _ = grid.nearest(q)
                ok = near2 >= 0
                sel, q = sel[ok], q[ok]
                dist2, m = self._exact_at(sel, q, near2[ok])
                again = dist2 < self.margin
                sel = sel[again]
                m = m[again] / np.maximum(np.linalg.norm(m[again], axis=1, keepdims=True), 1e-12)
                disp = push[sel, None] * self.direction[sel] + (self.target[sel] - dist2[again])[:, None] * m
                p = np.linalg.norm(disp, axis=1)
                push[sel] = p
                nz = p > 0
                self.direction[sel[nz]] = disp[nz] / p[nz, None]
        push[push < 1e-5] = 0.0
        self.push = push
        moving = np.flatnonzero(push)
        out = item_points.copy()
        out[moving] += push[moving, None] * self.direction[moving]
        out = self._deep(item_points, out, self.outside0 & ~np.isfinite(approx))
        return self._smoothed(item_points, self._checked(item_points, out, before)), n_inside

    def _deep(self, item_points: np.ndarray, out: np.ndarray, far: np.ndarray) -> np.ndarray:
        """Guarded vertices with no body vertex within ``radius`` (``far``
        (M,) bool, where the frame's pass found none: it takes them for far
        outside) that are deep inside instead: the body vertex nearest to
        them within ``DEEP_REACH`` has them behind its tangent plane. Their
        exact signed distance among the whole-body check's candidates
        (:meth:`_check_candidates`) gives the push out to their clearance.
        A body part that came through them faster than the radius per frame
        left them there: the back of a long skirt's waistband, 3 cm off the
        buttocks in a dance's first pose, was 5-6 cm inside them 300 frames
        later (the CMU dance with the arms held high), under the hot pants.
        Updates the push state; returns ``out``."""
        idx = np.flatnonzero(far)
        if len(idx) == 0:
            return out
        if self._deep_reach is None:
            # a coarse body's vertices are farther apart than that
            self._deep_reach = max(self.DEEP_REACH, 1.5 * edge_length_percentile(self.query.points, self.faces))
        # last frame's answer bounds the search (the same answer, fewer cells)
        vi, _ = self._frame_grid().nearest(item_points[idx], hint=self._deep_hint[idx], radius=self._deep_reach)
        self._deep_hint[idx] = vi
        ok = vi >= 0
        idx, vi = idx[ok], vi[ok]
        if len(idx) == 0:
            return out
        # the side of the vertex's plane: the sum of its triangles' normals
        # (the ring's padding repeats one: the sign is what counts)
        n = self.query.face_normal[self.query.ring[vi]].sum(axis=1)
        behind = np.einsum("ij,ij->i", item_points[idx] - self.query.points[vi], n) < 0.0
        sel = idx[behind]
        if len(sel) == 0:
            return out
        res = self.query.closest(item_points[sel], candidates=self._check_candidates(sel, item_points[sel]),
                                 ring=False)
        p = self.target[sel] - res["distance"]
        deeper = p > np.maximum(self.push[sel], 1e-5)
        sel, p = sel[deeper], p[deeper]
        if len(sel) == 0:
            return out
        d = res["normal"][deeper]
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        self.push[sel] = p
        self.direction[sel] = d
        out[sel] = item_points[sel] + p[:, None] * d
        return out

    def _checked(self, item_points: np.ndarray, out: np.ndarray, before=None) -> np.ndarray:
        """The pushed vertices checked against the whole body (the closest
        point among a wider set of triangles, :meth:`_check_candidates`),
        where they were before the push: one inside, or within its
        clearance, is pushed from there along the normal of its true closest
        feature, to its clearance; one that is outside by its clearance is
        not pushed at all. The frame's few candidate triangles (frame 0's and
        the ring of the nearest body vertex) miss the closest one where the
        body's triangles are large or its parts overlap: on a low-poly game
        body the push followed a wrong normal, into the body; on a dense one,
        with an arm crossing the hip, a waistband vertex 5 mm outside the hip
        was found inside the arm and pushed 28 mm through it, dragging its
        neighbours 0.6 mm away into the body. Updates the push state;
        returns ``out``. ``before``: the pushes (M,) and directions (M, 3)
        the frame started from, decayed; only the pushes this frame set or
        turned are checked (a push that only decays was checked when it was
        set). None: every pushed vertex."""
        if not self.check_pushes:
            return out
        pushed = self.push > 0
        if before is not None:
            pushed &= (np.abs(self.push - before[0]) > 1e-9) | np.any(self.direction != before[1], axis=1)
        sel = np.flatnonzero(pushed)
        if len(sel) == 0:
            return out
        res = self.query.closest(item_points[sel], candidates=self._check_candidates(sel, item_points[sel]),
                                 ring=False)
        n = res["normal"] / np.maximum(np.linalg.norm(res["normal"], axis=1, keepdims=True), 1e-12)
        p = np.maximum(self.target[sel] - res["distance"], 0.0)
        p[p < 1e-5] = 0.0
        self.push[sel] = p
        self.direction[sel] = n
        out[sel] = item_points[sel] + p[:, None] * n
        return out

    def _check_candidates(self, idx: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Candidate triangles (len(idx), c) for the whole-body check of
        item vertices idx placed at points (len(idx), 3): their frame-0
        triangles, the ring of the body vertex nearest to them now, the
        triangle whose centroid is nearest now and the ring of its corner
        nearest to them (on a coarse body the nearest vertex can be far from
        the closest triangle; the centroid finds it). Two uniform grids
        rebuilt per frame (KD-trees cost 14 ms a frame on a 27k-triangle
        body)."""
        vi, _ = self._frame_grid().nearest(points)
        cents = self.query.centroids
        if self._cgrid is None:
            # searched as far as the body's long edges (a coarse body's centroids are far apart)
            reach = 1.5 * edge_length_percentile(self.query.points, self.faces)
            self._cgrid = RadiusGrid(cents, max(self.radius, reach))
        elif self._cgrid.points is not cents:
            self._cgrid.update(cents)
        ci, _ = self._cgrid.nearest(points)
        miss = np.flatnonzero(ci < 0)
        if len(miss):
            # deeper in the body than the grid's radius from every centroid
            # (a vertex 6 cm inside a thigh): searched farther, not left to
            # its frame-0 triangles, which a fast limb has carried away (a
            # skirt's waistband vertex measured 49 cm "inside" those and
            # was pushed that far)
            ci[miss] = self._cgrid.nearest(points[miss], radius=self.FAR_CHECK)[0]
        c0 = self.cand0[idx]
        vi = np.where(vi < 0, self.faces[c0[:, 0], 0], vi)
        ci = np.where(ci < 0, c0[:, 0], ci)
        ring, corners = self.query.ring, self.faces[ci]
        # of that triangle's corners, the one nearest to the point
        dc = np.linalg.norm(self.query.points[corners] - points[:, None, :], axis=2)
        corner = corners[np.arange(len(ci)), np.argmin(dc, axis=1)]
        return np.concatenate([c0, ring[vi], ring[corner], ci[:, None]], axis=1)

    SMOOTH_ITERATIONS = 3

    def _smoothed(self, before: np.ndarray, out: np.ndarray) -> np.ndarray:
        """The pushes spread over the item's edges (with ``item_neighbours``):
        the displacement ``out - before`` averaged with its neighbours'
        (SMOOTH_ITERATIONS Jacobi steps, half own, half neighbours'), then
        every pushed vertex given back what it lost along its own push."""
        if self._walk is None:
            return out
        d0 = out - before
        pushed = np.flatnonzero(np.any(d0 != 0.0, axis=1))
        if len(pushed) == 0:
            return out
        d = d0
        n0 = np.linalg.norm(d0[pushed], axis=1)
        u = d0[pushed] / np.maximum(n0, 1e-12)[:, None]
        for _ in range(self.SMOOTH_ITERATIONS):
            d = 0.5 * d + 0.5 * (self._walk @ d)
            # every pushed vertex keeps at least its own push, at each step
            short = n0 - np.einsum("ij,ij->i", d[pushed], u)
            d[pushed] += np.maximum(short, 0.0)[:, None] * u
        return before + d

    def inside_fraction(self, body_points: np.ndarray, item_points: np.ndarray) -> float:
        """Fraction of guarded item vertices (outside the body at frame 0)
        inside the body by more than the margin now. Exact closest-point test
        for every vertex whose cheap estimate is under 1 cm; the others are
        clearly outside."""
        self.update(body_points)
        est, vi = self.estimate(item_points)
        near = np.flatnonzero(self.outside0 & (est < 0.01))
        if len(near) == 0:
            return 0.0
        sd, _ = self.exact(near, item_points, vi[near])
        return float(np.sum(sd < -self.margin)) / max(int(self.outside0.sum()), 1)
