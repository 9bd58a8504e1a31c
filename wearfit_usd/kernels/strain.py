"""The strain limit's per-frame pass (:mod:`animate.strain_limit`), compiled.

Per pass, a loop over the edges that can be over (all in the first pass,
then those at a vertex the last pass moved), in ascending edge order on
even passes and descending on odd ones. An edge longer than ``limit`` x
its rest length gets its allowed length (computed once per frame, from
the principal stretches of the body triangles under its ends and the
offset factor of its clearance, as
:func:`dress.body_stretch.principal_stretches` and
:func:`dress.body_stretch.offset_factor` compute them), and one over its
allowed length (by more than ``OVER_SLACK``) moves its ends toward each
other at once (Gauss-Seidel: the next edge sees them moved), cut where a
move would go into the body (not for a vertex more than ``foot_lost``
behind the skin under it: that skin is not under it any more); an edge
with an end on this frame's plane (a cloth floor) or nearer the skin than
``near_skin`` when the call starts
instead stores its correction, and after the loop each vertex
at such an edge takes the mean of its corrections (gathered over its own
edges in ascending order; Jacobi), cut likewise; then every weld group
(item vertices joined by sub-millimetre edges,
:class:`animate.short_edges.ShortEdgeWeld`) is clamped to its rest reach
about its centre, so a pass cannot open a weld that the weld after the
limit would close by stretching the group's other edges. The numpy twin is
:meth:`animate.strain_limit.StrainLimit` itself (its ``compiled=False``
path): the same order as waves of edges that share no vertex
(:func:`wavefront_levels`), each wave at once; a test runs both.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .jit import jit

#: a weld group's member is clamped back only when farther from its group's
#: centre than its rest reach times (1 + this): one the last pass's clamp left
#: at its reach (to rounding) is not moved again, and the compiled pass and
#: its numpy twin, which round the centre differently, agree on which moved
REACH_SLACK = 1e-9
#: an edge is over its allowed length only when longer than it times (1 + this):
#: one a pass brought to its bound (to rounding) is not moved again, so a pass
#: with nothing left to do ends the frame's passes (and the two paths, which
#: round differently, agree on which edges are over)
OVER_SLACK = 1e-9


class StrainRest(NamedTuple):
    """What a frame's pass needs from the rest state, built once.

    edges (E, 2) int64, len0 (E,); local (M, L) int64 body triangles under
    each item vertex; faces (T, 3) int64; gram (T, 3) the rest triangles'
    edge Gram entries (e1.e1, e1.e2, e2.e2); foot_tri (M,) int64 and
    foot_bary (M, 3) each vertex's closest skin point at rest, foot0 (M, 3)
    that point and normal0 (M, 3) the unit normal there (interpolated
    vertex normals); clear0 (M,) the vertex's rest clearance; inc_ptr,
    inc_edge the edges at each vertex (:func:`edge_incidence`); group_ptr
    (G + 1,), group_rows (R,) int64 the weld groups' members as CSR rows and
    group_reach (R,) each member's rest distance from its group's centre
    (:func:`weld_groups`)."""
    edges: np.ndarray
    len0: np.ndarray
    local: np.ndarray
    faces: np.ndarray
    gram: np.ndarray
    foot_tri: np.ndarray
    foot_bary: np.ndarray
    foot0: np.ndarray
    normal0: np.ndarray
    clear0: np.ndarray
    inc_ptr: np.ndarray
    inc_edge: np.ndarray
    group_ptr: np.ndarray
    group_rows: np.ndarray
    group_reach: np.ndarray


def edge_incidence(edges: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The edges (E, 2) at each of ``n_points`` vertices as CSR rows:
    (ptr (n_points + 1,) int64, edge indices (2E,) int64, ascending within
    a row)."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    ends = e.ravel()
    order = np.argsort(ends, kind="stable")   # stable: a row's edges ascending
    ptr = np.zeros(n_points + 1, dtype=np.int64)
    np.cumsum(np.bincount(ends, minlength=n_points), out=ptr[1:])
    return ptr, (order // 2).astype(np.int64)


def weld_groups(rows: np.ndarray, group: np.ndarray, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weld groups (:class:`animate.short_edges.ShortEdgeWeld`'s ``rows``,
    ``group`` 0..G-1 and ``reach``, each (R,)) as :class:`StrainRest`'s
    (group_ptr (G + 1,) int64, group_rows (R,) int64 ascending within a
    group, group_reach (R,) float64 in that order); empty: no groups."""
    rows = np.asarray(rows, dtype=np.int64).ravel()
    group = np.asarray(group, dtype=np.int64).ravel()
    reach = np.asarray(reach, dtype=np.float64).ravel()
    if not (rows.shape == group.shape == reach.shape):
        raise ValueError(f"rows {rows.shape}, group {group.shape} and reach {reach.shape} do not match")
    n = int(group.max()) + 1 if len(group) else 0
    if len(group) and (group.min() < 0 or np.bincount(group).min() < 1):
        raise ValueError("weld groups must be numbered 0..G-1, each with a member")
    order = np.lexsort((rows, group))
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(group, minlength=n), out=ptr[1:])
    return ptr, rows[order], reach[order]


def wavefront_levels(edges: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The Gauss-Seidel passes' order as waves: (forward (E,), backward
    (E,)) int64, each edge's wave when the edges (E, 2) are taken one by
    one in ascending (descending) index order: one more than the last wave
    to touch either of its ends. Edges of one wave share no vertex, and an
    edge comes after every earlier edge at its ends: taking the waves in
    turn, each at once, gives what the one-by-one loop gives, for the
    edges of any subset too (the numpy twin's schedule)."""
    e = np.ascontiguousarray(edges, dtype=np.int64).reshape(-1, 2)
    fwd = np.empty(len(e), dtype=np.int64)
    bwd = np.empty(len(e), dtype=np.int64)
    _levels(e, n_points, fwd, bwd)
    return fwd, bwd


@jit
def _levels(edges, n_points, fwd, bwd):
    last = np.zeros(n_points, dtype=np.int64)
    for k in range(edges.shape[0]):
        a, b = edges[k, 0], edges[k, 1]
        lv = max(last[a], last[b]) + 1
        fwd[k] = lv
        last[a] = lv
        last[b] = lv
    last[:] = 0
    for k in range(edges.shape[0] - 1, -1, -1):
        a, b = edges[k, 0], edges[k, 1]
        lv = max(last[a], last[b]) + 1
        bwd[k] = lv
        last[a] = lv
        last[b] = lv


@jit(inline=True)
def _tri_hi(gram, faces, body, t):
    """Largest principal stretch of triangle t from its rest Gram entries to body."""
    a, b, c = gram[t, 0], gram[t, 1], gram[t, 2]
    i, j, k = faces[t, 0], faces[t, 1], faces[t, 2]
    e1x, e1y, e1z = body[j, 0] - body[i, 0], body[j, 1] - body[i, 1], body[j, 2] - body[i, 2]
    e2x, e2y, e2z = body[k, 0] - body[i, 0], body[k, 1] - body[i, 1], body[k, 2] - body[i, 2]
    d = e1x * e1x + e1y * e1y + e1z * e1z
    e = e1x * e2x + e1y * e2y + e1z * e2z
    f = e2x * e2x + e2y * e2y + e2z * e2z
    det = a * c - b * b
    if not det > 1e-12 * max(a * c, 1e-300):
        return 1.0
    tr = (c * d - 2.0 * b * e + a * f) / det
    dt = (d * f - e * e) / det
    disc = math.sqrt(max(0.25 * tr * tr - dt, 0.0))
    return math.sqrt(max(0.5 * tr + disc, 0.0))


@jit(inline=True)
def _foot(body, normals, faces, foot_tri, foot_bary, v, out):
    """The skin point under item vertex v on body (out[0:3]) and its unit
    interpolated normal (out[3:6])."""
    for c in range(6):
        out[c] = 0.0
    for k in range(3):
        q = faces[foot_tri[v], k]
        w = foot_bary[v, k]
        for c in range(3):
            out[c] += w * body[q, c]
            out[3 + c] += w * normals[q, c]
    ln = math.sqrt(out[3] * out[3] + out[4] * out[4] + out[5] * out[5])
    ln = max(ln, 1e-300)
    for c in range(3):
        out[3 + c] /= ln


@jit
def _vertex_hi(rest, body, tri_hi, v):
    """Largest principal stretch over the body triangles under item vertex v
    (tri_hi: this frame's per-triangle values, -1 where not computed yet)."""
    hi = 0.0
    for k in range(rest.local.shape[1]):
        t = rest.local[v, k]
        if tri_hi[t] < 0.0:
            tri_hi[t] = _tri_hi(rest.gram, rest.faces, body, t)
        hi = max(hi, tri_hi[t])
    return hi


@jit
def _skin_cap(rest, body, limit, ei, tri_hi, vhi):
    """limit x rest length x the skin's stretch under edge ei: its allowed
    length without the offset factor (which only raises it: a lower bound)."""
    a, b = rest.edges[ei, 0], rest.edges[ei, 1]
    if vhi[a] < 0.0:
        vhi[a] = _vertex_hi(rest, body, tri_hi, a)
    if vhi[b] < 0.0:
        vhi[b] = _vertex_hi(rest, body, tri_hi, b)
    return limit * rest.len0[ei] * max(vhi[a], vhi[b])


@jit
def _offset_factor(rest, body, normals, ei, feet, have_foot):
    """The offset factor of edge ei (:func:`dress.body_stretch.offset_factor`);
    feet (M, 6) a per-vertex cache of this frame's skin point and normal
    (have_foot (M,) where filled)."""
    a, b = rest.edges[ei, 0], rest.edges[ei, 1]
    if not have_foot[a]:
        _foot(body, normals, rest.faces, rest.foot_tri, rest.foot_bary, a, feet[a])
        have_foot[a] = True
    if not have_foot[b]:
        _foot(body, normals, rest.faces, rest.foot_tri, rest.foot_bary, b, feet[b])
        have_foot[b] = True
    c = max(0.5 * (rest.clear0[a] + rest.clear0[b]), 0.0)
    l2r = 0.0
    kr = 0.0
    l2f = 0.0
    kf = 0.0
    for i in range(3):
        dr = rest.foot0[b, i] - rest.foot0[a, i]
        l2r += dr * dr
        kr += (rest.normal0[b, i] - rest.normal0[a, i]) * dr
        df = feet[b, i] - feet[a, i]
        l2f += df * df
        kf += (feet[b, 3 + i] - feet[a, 3 + i]) * df
    ga = 1.0 + c * kr / max(l2r, 1e-300)
    gb = 1.0 + c * kf / max(l2f, 1e-300)
    third = rest.len0[ei] / 3.0
    if l2r > third * third and ga > 0.5 and gb > 0.5:
        return max(gb / max(ga, 0.5), 1.0)
    return 1.0


class StrainCaps(NamedTuple):
    """One body's allowed edge lengths, filled as the passes need them: a
    frame's later calls on the same body (the rounds after the weld) reuse
    them (:func:`new_caps` makes them; a new body needs new ones, or
    :func:`clear_caps`). cap (E,) -1 where not computed; exact (E,) cap
    includes the offset factor (else the skin's lower bound); tri_hi (T,)
    and vhi (M,) the triangles' and vertices' largest stretches (-1: not
    yet); feet (M, 6) and have_foot (M,) the skin points and normals under
    the vertices."""
    cap: np.ndarray
    exact: np.ndarray
    tri_hi: np.ndarray
    vhi: np.ndarray
    feet: np.ndarray
    have_foot: np.ndarray


def new_caps(n_edges: int, n_points: int, n_faces: int) -> StrainCaps:
    """Empty :class:`StrainCaps` for a rest state of these sizes."""
    return StrainCaps(np.full(n_edges, -1.0), np.zeros(n_edges, dtype=np.bool_), np.full(n_faces, -1.0),
                      np.full(n_points, -1.0), np.empty((n_points, 6)), np.zeros(n_points, dtype=np.bool_))


def clear_caps(caps: StrainCaps) -> None:
    """Forget every computed cap (a new body)."""
    caps.cap[:] = -1.0
    caps.exact[:] = False
    caps.tri_hi[:] = -1.0
    caps.vhi[:] = -1.0
    caps.have_foot[:] = False


def strain_frame(rest, body, normals, points, w, limit, iterations, margin, caps: StrainCaps | None = None,
                 planes: np.ndarray | None = None, near_skin: float = 0.0, foot_lost: float = math.inf) -> int:
    """One frame's strain limit, in place on points (M, 3); w (M,) the
    vertices' inverse masses (0: fixed). ``caps``: the allowed lengths on
    this body known from an earlier call (updated); None: computed afresh.
    ``planes`` (M, 6): a second floor per vertex this frame, a point (3) and
    a unit normal (3) no move may take it behind (a zero normal: none).
    ``near_skin``: a vertex closer than this to the skin under it when the
    call starts takes the Jacobi mean, as one with a plane does.
    ``foot_lost``: a vertex farther than this behind the skin under it is
    not over that skin any more: no move of it is cut there and it does not
    count as at the skin (``animate.strain_limit.FOOT_LOST``; default: every
    vertex is over its skin).
    Returns the number of edges it shortened."""
    if caps is None:
        caps = new_caps(rest.edges.shape[0], points.shape[0], rest.faces.shape[0])
    if planes is None:
        planes = np.zeros((points.shape[0], 6))
    return _strain_frame(rest, body, normals, points, w, limit, iterations, margin, caps, planes, float(near_skin),
                         float(foot_lost))


@jit(inline=True)
def _skin_clearance(rest, body, points, v):
    """The unit normal of the skin under vertex v (its rest closest triangle
    on this body) and v's height over that skin along it (at the same
    barycentrics): (nx, ny, nz, clearance)."""
    t = rest.foot_tri[v]
    i, j, k2 = rest.faces[t, 0], rest.faces[t, 1], rest.faces[t, 2]
    e1x, e1y, e1z = body[j, 0] - body[i, 0], body[j, 1] - body[i, 1], body[j, 2] - body[i, 2]
    e2x, e2y, e2z = body[k2, 0] - body[i, 0], body[k2, 1] - body[i, 1], body[k2, 2] - body[i, 2]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    nl = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
    nx, ny, nz = nx / nl, ny / nl, nz / nl
    px, py, pz = 0.0, 0.0, 0.0
    for q in range(3):
        bw = rest.foot_bary[v, q]
        vq = rest.faces[t, q]
        px += bw * body[vq, 0]
        py += bw * body[vq, 1]
        pz += bw * body[vq, 2]
    return nx, ny, nz, (points[v, 0] - px) * nx + (points[v, 1] - py) * ny + (points[v, 2] - pz) * nz


@jit(inline=True)
def _move(rest, body, points, planes, margin, foot_lost, v, sx, sy, sz):
    """Move vertex v by (sx, sy, sz), the part into the body cut to what
    keeps it ``margin`` outside the skin under it (its rest closest
    triangle on this body; not when v is more than ``foot_lost`` behind it)
    and not behind its plane (``planes[v]``)."""
    nx, ny, nz, clear = _skin_clearance(rest, body, points, v)
    if clear > -foot_lost:  # else that skin is not under it
        inward = -(sx * nx + sy * ny + sz * nz)
        cut = max(inward - max(clear - margin, 0.0), 0.0)
        sx += cut * nx
        sy += cut * ny
        sz += cut * nz
    # and not behind this frame's own plane, where it has one
    gx, gy, gz = planes[v, 3], planes[v, 4], planes[v, 5]
    clear = (points[v, 0] - planes[v, 0]) * gx + (points[v, 1] - planes[v, 1]) * gy + \
        (points[v, 2] - planes[v, 2]) * gz
    inward = -(sx * gx + sy * gy + sz * gz)
    cut = max(inward - max(clear, 0.0), 0.0)
    points[v, 0] += sx + cut * gx
    points[v, 1] += sy + cut * gy
    points[v, 2] += sz + cut * gz


@jit(inline=True)
def _has_floor(planes, v):
    """Whether vertex v has a plane this frame (a nonzero normal)."""
    return planes[v, 3] != 0.0 or planes[v, 4] != 0.0 or planes[v, 5] != 0.0


@jit
def _strain_frame(rest, body, normals, points, w, limit, iterations, margin, caps, planes, near_skin, foot_lost):
    """:func:`strain_frame`'s passes. Each pass looks at the edges that can
    be over, in ascending edge order on even passes and descending on odd
    ones: all in the first pass, then those at a vertex the last pass moved
    and those at a vertex this pass moved before their turn (the others
    keep their length: as if it looked at all). An edge over its cap with
    no end on a plane or at the skin moves its ends at once (Gauss-Seidel);
    one with such an end stores its correction, and after the loop each vertex at
    such an edge gathers its corrections over its own edges in ascending
    edge order (the Jacobi mean) and moves; then the weld groups are
    clamped to their rest reach, a member the clamp moved joining the next
    pass. A pass scans the range of edge indices marked for it."""
    n_e = rest.edges.shape[0]
    m = points.shape[0]
    cap, exact, tri_hi, vhi, feet, have_foot = caps
    limited = np.zeros(n_e, dtype=np.bool_)
    n_limited = 0
    over_pass = np.full(n_e, -1, dtype=np.int64)     # the pass in which a plane edge was over its cap
    corr = np.empty((n_e, 4))                         # its correction then: f, dx, dy, dz
    share = np.empty(n_e)                             # and end a's share
    mark = np.zeros(n_e, dtype=np.int64)              # the pass that looks at an edge (all: the first)
    lo, hi = 0, n_e - 1                               # the marked edges' range
    jacobi = np.empty(n_e, dtype=np.int64)            # the pass's active edges with an end on a plane or at the skin
    ends = np.empty(m, dtype=np.int64)                # the vertices at a plane edge over its cap
    vert_seen = np.full(m, -1, dtype=np.int64)
    moved = np.empty(m, dtype=np.int64)
    moved_seen = np.full(m, -1, dtype=np.int64)
    on_plane = np.zeros(m, dtype=np.bool_)           # the vertices that take the Jacobi mean
    for v in range(m):
        c = _skin_clearance(rest, body, points, v)[3]
        on_plane[v] = _has_floor(planes, v) or -foot_lost < c < near_skin
    for it in range(iterations):
        n_moved = 0
        n_jacobi = 0
        forward = it % 2 == 0
        k = lo if forward else hi
        while lo <= k <= hi:
            ei = k
            k = k + 1 if forward else k - 1
            if mark[ei] != it:
                continue
            a, b = rest.edges[ei, 0], rest.edges[ei, 1]
            if on_plane[a] or on_plane[b]:
                jacobi[n_jacobi] = ei
                n_jacobi += 1
                continue
            dx, dy, dz, ln = _edge(points, a, b)
            if not ln > limit * rest.len0[ei] or not _over(rest, body, normals, limit, caps, ei, ln):
                continue
            n_limited += not limited[ei]
            limited[ei] = True
            wa, wb = w[a], w[b]
            sa = wa / max(wa + wb, 1e-300)
            f = (ln - cap[ei]) / max(ln, 1e-300)
            for end in range(2):
                v = a if end == 0 else b
                wv = wa if end == 0 else wb
                if not wv > 0.0:
                    continue
                g = f * sa if end == 0 else -f * (1.0 - sa)
                _move(rest, body, points, planes, margin, foot_lost, v, g * dx, g * dy, g * dz)
                if moved_seen[v] != it:
                    moved_seen[v] = it
                    moved[n_moved] = v
                    n_moved += 1
                # the edges at v still to come in this pass's order are looked at too
                for j in range(rest.inc_ptr[v], rest.inc_ptr[v + 1]):
                    ej = rest.inc_edge[j]
                    if mark[ej] != it and (ej > ei if forward else ej < ei):
                        mark[ej] = it
                        hi = max(hi, ej)
                        lo = min(lo, ej)
        # the edges with an end on a plane: Jacobi, on the points the sweep left
        n_ends = 0
        for k in range(n_jacobi):
            ei = jacobi[k]
            a, b = rest.edges[ei, 0], rest.edges[ei, 1]
            dx, dy, dz, ln = _edge(points, a, b)
            if not ln > limit * rest.len0[ei] or not _over(rest, body, normals, limit, caps, ei, ln):
                continue
            n_limited += not limited[ei]
            limited[ei] = True
            wa, wb = w[a], w[b]
            share[ei] = wa / max(wa + wb, 1e-300)
            corr[ei, 0] = (ln - cap[ei]) / max(ln, 1e-300)
            corr[ei, 1] = dx
            corr[ei, 2] = dy
            corr[ei, 3] = dz
            over_pass[ei] = it
            if vert_seen[a] != it:
                vert_seen[a] = it
                ends[n_ends] = a
                n_ends += 1
            if vert_seen[b] != it:
                vert_seen[b] = it
                ends[n_ends] = b
                n_ends += 1
        if n_ends == 0 and n_moved == 0:
            break
        for k in range(n_ends):
            v = ends[k]
            sx, sy, sz, cnt = 0.0, 0.0, 0.0, 0.0
            for j in range(rest.inc_ptr[v], rest.inc_ptr[v + 1]):
                ei = rest.inc_edge[j]
                if over_pass[ei] != it:
                    continue
                f, sa = corr[ei, 0], share[ei]
                if rest.edges[ei, 0] == v:
                    sx += f * corr[ei, 1] * sa
                    sy += f * corr[ei, 2] * sa
                    sz += f * corr[ei, 3] * sa
                else:
                    sx -= f * corr[ei, 1] * (1.0 - sa)
                    sy -= f * corr[ei, 2] * (1.0 - sa)
                    sz -= f * corr[ei, 3] * (1.0 - sa)
                if w[v] > 0.0:
                    cnt += 1.0
            if not cnt > 0.0:
                continue
            _move(rest, body, points, planes, margin, foot_lost, v, sx / cnt, sy / cnt, sz / cnt)
            if moved_seen[v] != it:
                moved_seen[v] = it
                moved[n_moved] = v
                n_moved += 1
        # the weld groups back within their rest reach (as ShortEdgeWeld does);
        # a member the clamp moves joins the next pass
        for g in range(rest.group_ptr.shape[0] - 1):
            j0, j1 = rest.group_ptr[g], rest.group_ptr[g + 1]
            cx, cy, cz = 0.0, 0.0, 0.0
            for j in range(j0, j1):
                v = rest.group_rows[j]
                cx += points[v, 0]
                cy += points[v, 1]
                cz += points[v, 2]
            inv = 1.0 / (j1 - j0)
            cx, cy, cz = cx * inv, cy * inv, cz * inv
            for j in range(j0, j1):
                v = rest.group_rows[j]
                dx, dy, dz = points[v, 0] - cx, points[v, 1] - cy, points[v, 2] - cz
                r = math.sqrt(dx * dx + dy * dy + dz * dz)
                if not r > rest.group_reach[j] * (1.0 + REACH_SLACK):
                    continue
                f = rest.group_reach[j] / r
                points[v, 0] = cx + dx * f
                points[v, 1] = cy + dy * f
                points[v, 2] = cz + dz * f
                if moved_seen[v] != it:
                    moved_seen[v] = it
                    moved[n_moved] = v
                    n_moved += 1
        # the next pass: the edges at the vertices this one moved
        lo, hi = n_e, -1
        for k in range(n_moved):
            v = moved[k]
            for j in range(rest.inc_ptr[v], rest.inc_ptr[v + 1]):
                ej = rest.inc_edge[j]
                mark[ej] = it + 1
                lo = min(lo, ej)
                hi = max(hi, ej)
    return n_limited


@jit(inline=True)
def _edge(points, a, b):
    """Edge a-b's vector (b - a) and length."""
    dx = points[b, 0] - points[a, 0]
    dy = points[b, 1] - points[a, 1]
    dz = points[b, 2] - points[a, 2]
    return dx, dy, dz, math.sqrt(dx * dx + dy * dy + dz * dz)


@jit(inline=True)
def _over(rest, body, normals, limit, caps, ei, ln):
    """Whether edge ei, ``ln`` long (already over ``limit`` x its rest
    length: the callers' cheap test), is over its allowed length on body
    (computed into ``caps`` the first time an edge needs it: the skin's
    lower bound first, the offset factor only if that is passed)."""
    cap, exact, tri_hi, vhi, feet, have_foot = caps
    if cap[ei] < 0.0:
        cap[ei] = _skin_cap(rest, body, limit, ei, tri_hi, vhi)
    if not ln > cap[ei] * (1.0 + OVER_SLACK):
        return False
    if not exact[ei]:
        cap[ei] *= _offset_factor(rest, body, normals, ei, feet, have_foot)
        exact[ei] = True
        if not ln > cap[ei] * (1.0 + OVER_SLACK):
            return False
    return True
