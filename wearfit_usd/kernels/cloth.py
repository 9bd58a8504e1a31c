"""The XPBD cloth step: one animation frame of the loose item vertices.

Extended position-based dynamics (Macklin, Mueller, Chentanez 2016, "XPBD:
Position-Based Simulation of Compliant Constrained Dynamics"), run as many
small substeps with one constraint pass each (Macklin et al. 2019, "Small
Steps in Physics Simulation"). The caller (:class:`animate.cloth.ClothSolver`)
builds the arrays once; :func:`cloth_frame` advances them by one frame.

Particles: the first ``n_free`` rows of ``x`` are simulated (inverse mass
``inv_m`` > 0); the others are kinematic (inverse mass 0): they sit on their
bound target every substep (the attachment line and the bound vertices next
to the simulated ones).

A frame of length ``dt`` is ``n_sub`` substeps of ``h = dt / n_sub``. Within
the frame the body and the bound targets move linearly from the previous
frame's (``b0``, ``t0``) to this frame's (``b1``, ``t1``); substep ``k``
(``s = (k + 1) / n_sub``) sees ``b(s) = (1 - s) b0 + s b1`` (the same for the
vertex normals, renormalised, and the targets). Each substep:

1. predict, with inertia: the velocity relative to the target's velocity
   ``u = (t1 - t0) / dt`` decays as ``v <- u + (v - u) exp(-damping h)``
   (damping that does not slow a garment walking with its body), gravity
   ``v <- v + g h``, and ``p = x + h v``;
2. ``n_iter`` passes over the cloth's own constraints (attachment,
   tethers, edges), then one over the body collisions; each as XPBD: for a constraint
   ``C(p)`` with compliance ``alpha`` (inverse stiffness) and accumulated
   multiplier ``lambda`` (zeroed at the start of the substep),

       alpha~ = alpha / h^2
       d_lambda = (-C - alpha~ lambda) / (sum_j w_j |grad_j C|^2 + alpha~)
       lambda += d_lambda;  p_j += w_j grad_j C d_lambda

   with ``w_j`` the inverse masses:

   * attachment (per free vertex, per axis): ``C = p - t(s)`` with
     compliance ``att_alpha`` (small near the attachment line, large where
     the cloth hangs free);
   * edge distance: ``C = |p_a - p_b| - L`` (``L`` its length in the
     static dress), compliance ``alpha_stretch`` when stretched and the
     softer ``alpha_compress`` when compressed (cloth buckles rather than
     shortens), in the order of ``edges`` (coloured so that no two edges of
     one colour share a vertex: the numpy twin updates a colour at once and
     gets the same numbers);
   * tether (long-range attachment, Kim, Chentanez, Mueller 2012): a free
     particle with an anchor ``a`` (the kinematic particle nearest along
     the cloth) stays within ``length`` of it, ``C = |p - p_a| - length <= 0``
     projected hard (the anchor does not move): the cloth as a whole cannot
     stretch away from where it hangs, whatever the chain of edges between
     (edges alone, one pass a substep, let a long skirt sag and its hem
     be pulled out); projected before the edges, which then smooth what
     the tethers moved (a tether pulling straight through a shoulder the
     hair lies on would otherwise hold edges stretched against the
     collision);
   * body collision (after the others, so it has the last word), per
     collision sample: a free particle, or the midpoint ``q = (p_a + p_b) / 2``
     of an edge (a knee between the vertices of a coarse skirt meets one).
     The body is the skin at ``b(s)``; the sample's nearest body vertex
     ``j`` is followed by a greedy walk over the body's vertex graph from
     the last one (``hint``, re-seeded from a grid search by the caller), in
     the frame's first substep; ``n_j`` is its unit normal,
     ``d = (q - b_j) . n_j`` the signed distance estimate, and
     ``C = d - m >= 0`` is projected hard (``alpha = 0``), ``m`` the
     sample's ``margin``, or where more the clearance of the items under its
     cloth item over vertex ``j`` (``ClothBody.layer[layer_row, j] - allow``,
     :func:`animate.cloth.inner_layer_field`): with
     ``grad_a C = g_a n`` (``g = 1`` for a particle, ``1/2`` for each end of
     an edge) each particle moves by ``w_a g_a / sum(w g^2) (m - d) n``,
     which moves the sample by exactly ``m - d``. A sample whose lower
     bound on its distance to the body vertices (``clear``, less the body's
     largest motion and its own since) exceeds ``top + gap`` (``top``: its
     largest ``m`` anywhere) is skipped.
     A fast leg could carry a sample past its middle, where the nearest
     vertex is on the far side: when the walk lands on a vertex whose normal
     opposes the previous one and the sample is within ``margin`` of the
     previous vertex's plane (previous frame's side), the previous vertex
     and its normal are kept. A sample more than ``MAX_SLIDE + gap`` from
     its vertex along the skin is not pushed (that tangent plane says
     nothing about it), and no push exceeds ``MAX_PUSH`` in one pass.
     Friction (position-level Coulomb): the
     sample's displacement tangential to ``n_j``, relative to the body
     vertex's motion in this substep, is removed up to ``friction * depth``;
3. ``v = (p - x) / h``, ``x = p``.

The kernel takes its arrays grouped as named tuples: :class:`ClothState`
(what the cloth carries from frame to frame), :class:`ClothTargets`,
:class:`ClothEdges`, :class:`ClothTethers`, :class:`ClothSamples`,
:class:`ClothBody` and :class:`ClothParams`. All arrays float64 (indices
int64) and C-contiguous; lengths in metres, times in seconds.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .jit import HAVE_NUMBA, jit

MAX_WALK = 24     # greedy steps per nearest-vertex walk (usually 0-2 are taken)
MAX_SLIDE = 0.03  # m: a sample farther than this (plus gap) from its body vertex along the skin is not pushed
MAX_PUSH = 0.03   # m: deepest push of a sample in one pass (deeper ones come out over the next substeps)


class ClothState(NamedTuple):
    """What the cloth carries from frame to frame (P particles, the first
    F = ``len(v)`` simulated, the rest kinematic)."""
    x: np.ndarray          # (P, 3) positions (updated)
    v: np.ndarray          # (F, 3) velocities (updated)
    inv_m: np.ndarray      # (P,) inverse masses (0: kinematic)
    att_alpha: np.ndarray  # (F,) attachment compliance (s^2)


class ClothTargets(NamedTuple):
    """The bound positions of the particles at the previous frame and at this one."""
    t0: np.ndarray  # (P, 3)
    t1: np.ndarray  # (P, 3)


class ClothEdges(NamedTuple):
    """The distance constraints, sorted by colour (no two edges of a colour share a particle)."""
    pairs: np.ndarray       # (E, 2) int64 particle pairs
    rest: np.ndarray        # (E,) rest lengths
    colour_ptr: np.ndarray  # (C + 1,) int64 start of each colour


class ClothTethers(NamedTuple):
    """Per free particle, the kinematic particle it hangs from and how far it may be."""
    anchor: np.ndarray  # (F,) int64 particle index (-1: none)
    length: np.ndarray  # (F,) largest distance from it


class ClothSamples(NamedTuple):
    """The collision samples (midpoints of two particles, a particle when both are one)."""
    pairs: np.ndarray       # (S, 2) int64, sorted by colour (no two of a colour share a particle)
    colour_ptr: np.ndarray  # (K + 1,) int64
    hint: np.ndarray        # (S,) int64 nearest body vertex (-1: none within reach; updated)
    margin: np.ndarray      # (S,) clearance kept from the body
    clear: np.ndarray       # (S,) lower bound of the distance to the body vertices (updated)
    layer_row: np.ndarray   # (S,) int64 row of ClothBody.layer the sample keeps over (-1: none)
    allow: np.ndarray       # (S,) how far the sample may stay under that row's clearance
    top: np.ndarray         # (S,) the largest clearance the sample keeps anywhere


class ClothBody(NamedTuple):
    """The collider over the frame: its vertices, unit normals and vertex graph."""
    b0: np.ndarray         # (N, 3) points at the previous frame
    b1: np.ndarray         # (N, 3) points at this frame
    n0: np.ndarray         # (N, 3) unit vertex normals at the previous frame
    n1: np.ndarray         # (N, 3) and at this one
    adj_ptr: np.ndarray    # (N + 1,) int64 CSR of the vertex graph
    adj_idx: np.ndarray    # (nnz,) int64
    adj_table: np.ndarray  # (N, D) int64 the same, -1 padded (numpy twin)
    layer: np.ndarray      # (R, N) clearance over each vertex of the items under a cloth item (row)
    move: float            # largest vertex displacement over the frame
    gap: float             # how much nearer than its nearest vertex the skin can be


class ClothParams(NamedTuple):
    """The frame length and the material."""
    gravity: np.ndarray     # (3,) m/s^2
    damping: float          # 1/s, of the velocity relative to the targets'
    friction: float         # Coulomb coefficient against the skin
    alpha_stretch: float    # s^2 edge compliance when stretched
    alpha_compress: float   # s^2 when compressed
    dt: float               # frame length (s)
    n_sub: int              # substeps
    n_iter: int             # constraint passes per substep


class ClothScratch(NamedTuple):
    """Work buffers of the compiled loop."""
    lam_e: np.ndarray  # (E,)
    lam_a: np.ndarray  # (F, 3)
    p: np.ndarray      # (P, 3)
    q0: np.ndarray     # (S, 3)


def make_scratch(n_edges: int, n_free: int, n_particles: int, n_samples: int) -> ClothScratch:
    """Buffers for :func:`cloth_frame` of these sizes."""
    return ClothScratch(np.empty(n_edges), np.empty((n_free, 3)), np.empty((n_particles, 3)),
                        np.empty((n_samples, 3)))


# ----------------------------------------------------------------------------
# compiled loop (numba); the numpy twin below gives the same numbers

def _lerp_normal(n0, n1, j, s):
    """Unit normal of body vertex j at substep parameter s: (nx, ny, nz)."""
    nx = n0[j, 0] * (1.0 - s) + n1[j, 0] * s
    ny = n0[j, 1] * (1.0 - s) + n1[j, 1] * s
    nz = n0[j, 2] * (1.0 - s) + n1[j, 2] * s
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    if ln > 1e-300:
        nx /= ln
        ny /= ln
        nz /= ln
    return nx, ny, nz


def _dist2_to(b0, b1, j, s, px, py, pz):
    """Squared distance from (px, py, pz) to body vertex j at substep s."""
    dx = px - (b0[j, 0] * (1.0 - s) + b1[j, 0] * s)
    dy = py - (b0[j, 1] * (1.0 - s) + b1[j, 1] * s)
    dz = pz - (b0[j, 2] * (1.0 - s) + b1[j, 2] * s)
    return dx * dx + dy * dy + dz * dz


def _collide(p, x, hint, samples, margin, clear, layer_row, allow, top, layer, q0, move, gap, friction, inv_m,
             b0, b1, n0, n1, adj_ptr, adj_idx, s_prev, s, walk):
    """Body collision of every collision sample (see the module docstring),
    one loop (a call per sample, passing these arrays, cost more than the
    test of a sample far from the body)."""
    for k in range(samples.shape[0]):
        h0 = hint[k]
        if h0 < 0:
            continue
        ia = samples[k, 0]
        ib = samples[k, 1]
        px = 0.5 * (p[ia, 0] + p[ib, 0])
        py = 0.5 * (p[ia, 1] + p[ib, 1])
        pz = 0.5 * (p[ia, 2] + p[ib, 2])
        # lower bound of the distance to the skin: skip the search when clear
        ex = px - q0[k, 0]
        ey = py - q0[k, 1]
        ez = pz - q0[k, 2]
        dq = math.sqrt(ex * ex + ey * ey + ez * ez)
        if clear[k] - move * s - dq > top[k] + gap:
            continue
        h = h0
        d2 = _dist2_to(b0, b1, h, s, px, py, pz)
        if walk:
            for _ in range(MAX_WALK):
                best = d2
                bj = -1
                for q in range(adj_ptr[h], adj_ptr[h + 1]):
                    j = adj_idx[q]
                    dj = _dist2_to(b0, b1, j, s, px, py, pz)
                    if dj < best:
                        best = dj
                        bj = j
                if bj < 0:
                    break
                h = bj
                d2 = best
            # a fresh bound: the nearest vertex's distance now
            clear[k] = math.sqrt(d2) + move * s + dq
        nx, ny, nz = _lerp_normal(n0, n1, h, s)
        bx = b0[h, 0] * (1.0 - s) + b1[h, 0] * s
        by = b0[h, 1] * (1.0 - s) + b1[h, 1] * s
        bz = b0[h, 2] * (1.0 - s) + b1[h, 2] * s
        d = (px - bx) * nx + (py - by) * ny + (pz - bz) * nz
        if h != h0:
            ox, oy, oz = _lerp_normal(n0, n1, h0, s)
            if ox * nx + oy * ny + oz * nz < 0.0:
                cx = b0[h0, 0] * (1.0 - s) + b1[h0, 0] * s
                cy = b0[h0, 1] * (1.0 - s) + b1[h0, 1] * s
                cz = b0[h0, 2] * (1.0 - s) + b1[h0, 2] * s
                d_old = (px - cx) * ox + (py - cy) * oy + (pz - cz) * oz
                if d_old < margin[k]:  # crossed over from the previous vertex's side
                    h = h0
                    nx = ox
                    ny = oy
                    nz = oz
                    bx = cx
                    by = cy
                    bz = cz
                    d = d_old
        hint[k] = h
        m = margin[k]
        r = layer_row[k]
        if r >= 0:
            m = max(m, layer[r, h] - allow[k])
        depth = m - d
        if depth <= 0.0:
            continue
        # the tangent plane of a vertex far to the side says nothing (a stale
        # vertex): no push; and no push deeper than MAX_PUSH in one pass
        ex = px - bx
        ey = py - by
        ez = pz - bz
        if ex * ex + ey * ey + ez * ez - d * d > (MAX_SLIDE + gap) * (MAX_SLIDE + gap):
            continue
        depth = min(depth, MAX_PUSH)
        # C = n . (q - b) - margin with q = (p_a + p_b) / 2 (p_a itself when a == b)
        wa = inv_m[ia]
        if ia == ib:
            ga = 1.0
            gb = 0.0
            wsum = wa
        else:
            ga = 0.5
            gb = 0.5
            wsum = 0.25 * (wa + inv_m[ib])
        if wsum <= 0.0:
            continue
        cx = depth * nx
        cy = depth * ny
        cz = depth * nz
        if friction > 0.0:
            # tangential displacement of the sample relative to the body vertex over this substep
            rx = px + cx - 0.5 * (x[ia, 0] + x[ib, 0]) - (bx - (b0[h, 0] * (1.0 - s_prev) + b1[h, 0] * s_prev))
            ry = py + cy - 0.5 * (x[ia, 1] + x[ib, 1]) - (by - (b0[h, 1] * (1.0 - s_prev) + b1[h, 1] * s_prev))
            rz = pz + cz - 0.5 * (x[ia, 2] + x[ib, 2]) - (bz - (b0[h, 2] * (1.0 - s_prev) + b1[h, 2] * s_prev))
            rn = rx * nx + ry * ny + rz * nz
            tx = rx - rn * nx
            ty = ry - rn * ny
            tz = rz - rn * nz
            tl = math.sqrt(tx * tx + ty * ty + tz * tz)
            lim = friction * depth
            if tl > 0.0:
                f = 1.0 if tl <= lim else lim / tl
                cx -= f * tx
                cy -= f * ty
                cz -= f * tz
        # the sample moves by c: each particle by w g / sum(w g^2) times c
        fa = wa * ga / wsum
        p[ia, 0] += fa * cx
        p[ia, 1] += fa * cy
        p[ia, 2] += fa * cz
        if ia != ib:
            fb = inv_m[ib] * gb / wsum
            p[ib, 0] += fb * cx
            p[ib, 1] += fb * cy
            p[ib, 2] += fb * cz


def _tethers(p, n_free, anchor, length):
    """Tethers of the free particles: each within length[i] of its
    (kinematic) anchor."""
    for i in range(n_free):
        a = anchor[i]
        if a < 0:
            continue
        dx = p[i, 0] - p[a, 0]
        dy = p[i, 1] - p[a, 1]
        dz = p[i, 2] - p[a, 2]
        ln = math.sqrt(dx * dx + dy * dy + dz * dz)
        if ln <= length[i]:
            continue
        f = (ln - length[i]) / ln
        p[i, 0] -= f * dx
        p[i, 1] -= f * dy
        p[i, 2] -= f * dz


def _frame_loop(state, tg, ed, te, sm, body, prm, scratch):
    """One frame (see the module docstring); the state, the samples' hint
    and clear, and the scratch buffers updated in place."""
    x, v, inv_m, att_alpha = state
    t0, t1 = tg
    edges, rest, _ = ed
    samples, _, hint, margin, clear, layer_row, allow, top = sm
    b0, b1, n0, n1, adj_ptr, adj_idx, _, layer, move, gap = body
    gravity, damping, friction, alpha_stretch, alpha_compress, dt, n_sub, n_iter = prm
    lam_e, lam_a, p, q0 = scratch
    n_free = v.shape[0]
    n_all = x.shape[0]
    for k in range(samples.shape[0]):
        for c in range(3):
            q0[k, c] = 0.5 * (x[samples[k, 0], c] + x[samples[k, 1], c])
    hs = dt / n_sub
    inv_hs = 1.0 / hs
    decay = math.exp(-damping * hs)
    # what stays the same over the frame's substeps and passes, once: the
    # compliances over h^2 and the reciprocals of the XPBD denominators
    # (w + alpha~), so the passes multiply instead of divide
    a_att = np.empty(n_free)
    k_att = np.empty(n_free)
    u = np.empty((n_free, 3))
    inv_dt = 1.0 / dt
    for i in range(n_free):
        a_att[i] = att_alpha[i] / (hs * hs)
        k_att[i] = 1.0 / (inv_m[i] + a_att[i])
        for c in range(3):
            u[i, c] = (t1[i, c] - t0[i, c]) * inv_dt
    a_str = alpha_stretch / (hs * hs)
    a_cmp = alpha_compress / (hs * hs)
    n_edges = edges.shape[0]
    k_str = np.empty(n_edges)
    k_cmp = np.empty(n_edges)
    for e in range(n_edges):
        ws = inv_m[edges[e, 0]] + inv_m[edges[e, 1]]
        k_str[e] = 1.0 / (ws + a_str)
        k_cmp[e] = 1.0 / (ws + a_cmp)
    for k_sub in range(n_sub):
        s_prev = k_sub / n_sub
        s = (k_sub + 1) / n_sub
        # predict, and the first pass's attachment (its multiplier starts at 0)
        for i in range(n_free):
            wi = inv_m[i]
            ki = k_att[i]
            for c in range(3):
                uc = u[i, c]
                vc = uc + (v[i, c] - uc) * decay + gravity[c] * hs
                v[i, c] = vc
                pc = x[i, c] + vc * hs
                dl = -(pc - (t0[i, c] * (1.0 - s) + t1[i, c] * s)) * ki
                lam_a[i, c] = dl
                p[i, c] = pc + wi * dl
        for i in range(n_free, n_all):
            for c in range(3):
                p[i, c] = t0[i, c] * (1.0 - s) + t1[i, c] * s
        lam_e[:] = 0.0
        for it in range(n_iter):
            for i in range(n_free if it > 0 else 0):
                a = a_att[i]
                ki = k_att[i]
                wi = inv_m[i]
                for c in range(3):
                    C = p[i, c] - (t0[i, c] * (1.0 - s) + t1[i, c] * s)
                    dl = (-C - a * lam_a[i, c]) * ki
                    lam_a[i, c] += dl
                    p[i, c] += wi * dl
            _tethers(p, n_free, te.anchor, te.length)
            for e in range(n_edges):
                ia = edges[e, 0]
                ib = edges[e, 1]
                wa = inv_m[ia]
                wb = inv_m[ib]
                dx = p[ia, 0] - p[ib, 0]
                dy = p[ia, 1] - p[ib, 1]
                dz = p[ia, 2] - p[ib, 2]
                ln = math.sqrt(dx * dx + dy * dy + dz * dz)
                if ln < 1e-12:
                    continue
                C = ln - rest[e]
                if C > 0.0:
                    dl = (-C - a_str * lam_e[e]) * k_str[e]
                else:
                    dl = (-C - a_cmp * lam_e[e]) * k_cmp[e]
                lam_e[e] += dl
                f = dl / ln
                p[ia, 0] += wa * f * dx
                p[ia, 1] += wa * f * dy
                p[ia, 2] += wa * f * dz
                p[ib, 0] -= wb * f * dx
                p[ib, 1] -= wb * f * dy
                p[ib, 2] -= wb * f * dz
        _collide(p, x, hint, samples, margin, clear, layer_row, allow, top, layer, q0, move, gap, friction, inv_m,
                 b0, b1, n0, n1, adj_ptr, adj_idx, s_prev, s, k_sub == 0)
        for i in range(n_free):
            for c in range(3):
                v[i, c] = (p[i, c] - x[i, c]) * inv_hs
                x[i, c] = p[i, c]
        for i in range(n_free, n_all):
            for c in range(3):
                x[i, c] = p[i, c]
    # the lower bounds age by the body's and the sample's motion over the frame
    for k in range(samples.shape[0]):
        ex = 0.5 * (x[samples[k, 0], 0] + x[samples[k, 1], 0]) - q0[k, 0]
        ey = 0.5 * (x[samples[k, 0], 1] + x[samples[k, 1], 1]) - q0[k, 1]
        ez = 0.5 * (x[samples[k, 0], 2] + x[samples[k, 1], 2]) - q0[k, 2]
        clear[k] -= move + math.sqrt(ex * ex + ey * ey + ez * ez)


if HAVE_NUMBA:
    _lerp_normal = jit(_lerp_normal, inline=True)
    _dist2_to = jit(_dist2_to, inline=True)
    _collide = jit(_collide)
    _tethers = jit(_tethers)
    _frame_loop = jit(_frame_loop)


# ----------------------------------------------------------------------------
# numpy twin

def _lerp_rows(a0, a1, idx, s):
    return a0[idx] * (1.0 - s) + a1[idx] * s


def _unit(n):
    ln = np.sqrt(n[:, 0] * n[:, 0] + n[:, 1] * n[:, 1] + n[:, 2] * n[:, 2])
    ok = ln > 1e-300
    n[ok] /= ln[ok, None]
    return n


def _dist2_rows(b0, b1, j, s, q):
    d = q - _lerp_rows(b0, b1, j, s)
    return d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]


def _collide_numpy(p, x, hint, samples, margin, clear, layer_row, allow, top, layer, q0, move, gap, friction, inv_m,
                   b0, b1, n0, n1, adj_table, s_prev, s, rows, walk):
    """:func:`_collide` for the samples ``rows`` (no two share a particle) at once."""
    rows = rows[hint[rows] >= 0]
    ia, ib = samples[rows, 0], samples[rows, 1]
    q = 0.5 * (p[ia] + p[ib])
    e = q - q0[rows]
    dq = np.sqrt(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2])
    keep = ~(clear[rows] - move * s - dq > top[rows] + gap)
    rows, ia, ib, q, dq = rows[keep], ia[keep], ib[keep], q[keep], dq[keep]
    if len(rows) == 0:
        return
    h0 = hint[rows]
    h = h0.copy()
    d2 = _dist2_rows(b0, b1, h, s, q)
    if walk:
        act = np.arange(len(rows))
        for _ in range(MAX_WALK):
            nb = adj_table[h[act]]                                   # (A, D), -1 padded
            valid = nb >= 0
            dn = _dist2_rows(b0, b1, np.where(valid, nb, 0), s, q[act][:, None, :])
            dn = np.where(valid, dn, np.inf)
            k = np.argmin(dn, axis=1)
            best = dn[np.arange(len(act)), k]
            better = best < d2[act]
            if not better.any():
                break
            act = act[better]
            h[act] = nb[better, k[better]]
            d2[act] = best[better]
        clear[rows] = np.sqrt(d2) + move * s + dq
    n = _unit(_lerp_rows(n0, n1, h, s))
    b = _lerp_rows(b0, b1, h, s)
    rel = q - b
    d = rel[:, 0] * n[:, 0] + rel[:, 1] * n[:, 1] + rel[:, 2] * n[:, 2]
    moved = h != h0
    if moved.any():
        o = _unit(_lerp_rows(n0, n1, h0, s))
        cosine = o[:, 0] * n[:, 0] + o[:, 1] * n[:, 1] + o[:, 2] * n[:, 2]
        c = _lerp_rows(b0, b1, h0, s)
        rel_o = q - c
        d_old = rel_o[:, 0] * o[:, 0] + rel_o[:, 1] * o[:, 1] + rel_o[:, 2] * o[:, 2]
        back = moved & (cosine < 0.0) & (d_old < margin[rows])
        h[back] = h0[back]
        n[back] = o[back]
        b[back] = c[back]
        d[back] = d_old[back]
    hint[rows] = h
    r = layer_row[rows]
    lift = np.where(r >= 0, layer[np.maximum(r, 0), h] - allow[rows], -np.inf)
    depth = np.maximum(margin[rows], lift) - d
    wa = inv_m[ia]
    same = ia == ib
    wsum = np.where(same, wa, 0.25 * (wa + inv_m[ib]))
    rel = q - b
    side = rel[:, 0] * rel[:, 0] + rel[:, 1] * rel[:, 1] + rel[:, 2] * rel[:, 2] - d * d
    hit = (depth > 0.0) & (wsum > 0.0) & ~(side > (MAX_SLIDE + gap) * (MAX_SLIDE + gap))
    depth = np.minimum(depth, MAX_PUSH)
    if not hit.any():
        return
    ia, ib, depth, n, b, h, q, wa, wsum, same = (ia[hit], ib[hit], depth[hit], n[hit], b[hit], h[hit], q[hit],
                                                 wa[hit], wsum[hit], same[hit])
    corr = depth[:, None] * n
    if friction > 0.0:
        r = q + corr - 0.5 * (x[ia] + x[ib]) - (b - _lerp_rows(b0, b1, h, s_prev))
        rn = r[:, 0] * n[:, 0] + r[:, 1] * n[:, 1] + r[:, 2] * n[:, 2]
        t = r - rn[:, None] * n
        tl = np.sqrt(t[:, 0] * t[:, 0] + t[:, 1] * t[:, 1] + t[:, 2] * t[:, 2])
        lim = friction * depth
        f = np.where(tl <= lim, 1.0, lim / np.where(tl > 0.0, tl, 1.0))
        f = np.where(tl > 0.0, f, 0.0)
        corr = corr - f[:, None] * t
    ga = np.where(same, 1.0, 0.5)
    fa = wa * ga / wsum
    p[ia] += fa[:, None] * corr
    two = ~same
    fb = inv_m[ib[two]] * 0.5 / wsum[two]
    p[ib[two]] += fb[:, None] * corr[two]


def _tether_numpy(p, anchor, length):
    """:func:`_tethers`, every free particle at once (the anchors are kinematic)."""
    i = np.flatnonzero(anchor >= 0)
    a = anchor[i]
    d = p[i] - p[a]
    ln = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])
    over = ln > length[i]
    f = (ln[over] - length[i][over]) / ln[over]
    p[i[over]] -= f[:, None] * d[over]


def _frame_numpy(state, tg, ed, te, sm, body, prm):
    """numpy twin of :func:`_frame_loop` (edges and samples updated one colour at a time)."""
    x, v, inv_m, att_alpha = state
    t0, t1 = tg
    edges, rest, colour_ptr = ed
    samples, sample_ptr, hint, margin, clear, layer_row, allow, top = sm
    b0, b1, n0, n1, _, _, adj_table, layer, move, gap = body
    gravity, damping, friction, alpha_stretch, alpha_compress, dt, n_sub, n_iter = prm
    n_free = len(v)
    hs = dt / n_sub
    decay = np.exp(-damping * hs)
    u = (t1[:n_free] - t0[:n_free]) / dt
    wi = inv_m[:n_free, None]
    a_att = (att_alpha / (hs * hs))[:, None]
    p = np.empty_like(x)
    q0 = 0.5 * (x[samples[:, 0]] + x[samples[:, 1]])
    for k in range(n_sub):
        s_prev = k / n_sub
        s = (k + 1) / n_sub
        v[:] = u + (v - u) * decay + gravity * hs
        p[:n_free] = x[:n_free] + v * hs
        p[n_free:] = t0[n_free:] * (1.0 - s) + t1[n_free:] * s
        tgt = t0[:n_free] * (1.0 - s) + t1[:n_free] * s
        lam_e = np.zeros(len(edges))
        lam_a = np.zeros((n_free, 3))
        for _ in range(n_iter):
            dl = (-(p[:n_free] - tgt) - a_att * lam_a) / (wi + a_att)
            lam_a += dl
            p[:n_free] += wi * dl
            _tether_numpy(p, te.anchor, te.length)
            for c in range(len(colour_ptr) - 1):
                sl = slice(colour_ptr[c], colour_ptr[c + 1])
                ia, ib = edges[sl, 0], edges[sl, 1]
                wa, wb = inv_m[ia], inv_m[ib]
                dvec = p[ia] - p[ib]
                ln = np.sqrt(dvec[:, 0] * dvec[:, 0] + dvec[:, 1] * dvec[:, 1] + dvec[:, 2] * dvec[:, 2])
                ok = ln >= 1e-12
                C = ln - rest[sl]
                a = np.where(C > 0.0, alpha_stretch, alpha_compress) / (hs * hs)
                d_l = np.where(ok, (-C - a * lam_e[sl]) / (wa + wb + a), 0.0)
                lam_e[sl] += d_l
                f = np.where(ok, d_l / np.where(ok, ln, 1.0), 0.0)
                p[ia] += (wa * f)[:, None] * dvec
                p[ib] -= (wb * f)[:, None] * dvec
        for c in range(len(sample_ptr) - 1):
            rows = np.arange(sample_ptr[c], sample_ptr[c + 1])
            _collide_numpy(p, x, hint, samples, margin, clear, layer_row, allow, top, layer, q0, move, gap, friction,
                           inv_m, b0, b1, n0, n1, adj_table, s_prev, s, rows, k == 0)
        v[:] = (p[:n_free] - x[:n_free]) / hs
        x[:] = p
    e = 0.5 * (x[samples[:, 0]] + x[samples[:, 1]]) - q0
    clear -= move + np.sqrt(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2])


def cloth_frame(state: ClothState, targets: ClothTargets, edges: ClothEdges, tethers: ClothTethers,
                samples: ClothSamples, body: ClothBody, params: ClothParams, compiled: bool | None = None,
                scratch: ClothScratch | None = None) -> None:
    """Advance the cloth by one frame of ``params.dt`` seconds, in place
    (``state.x``, ``state.v``, ``samples.hint``, ``samples.clear``).

    Parameters
    ----------
    state : :class:`ClothState`, the particles (updated).
    targets : :class:`ClothTargets`, their bound positions at the previous
        frame and at this one.
    edges : :class:`ClothEdges`, the distance constraints.
    tethers : :class:`ClothTethers`, each free particle's largest distance
        from the kinematic particle it hangs from.
    samples : :class:`ClothSamples`, the collision samples; ``hint`` is
        each sample's nearest body vertex (-1: no body within reach this
        frame: not tested), ``clear`` a lower bound of its distance to the
        body vertices at the start of the frame (the search is skipped
        while the bound, less the motion since, stays above ``top +
        gap``; aged by the frame's motion on return); ``margin``,
        ``layer_row`` and ``allow`` give the clearance kept (module
        docstring).
    body : :class:`ClothBody`, the collider at the previous frame and this one.
    params : :class:`ClothParams`, frame length, substeps and material.
    compiled : use the numba loop (default: when numba is installed).
    scratch : optional :func:`make_scratch` buffers for the numba loop.
    """
    use = HAVE_NUMBA if compiled is None else bool(compiled and HAVE_NUMBA)
    body = body._replace(move=float(body.move), gap=float(body.gap))
    params = ClothParams(np.asarray(params.gravity, dtype=np.float64), float(params.damping),
                         float(params.friction), float(params.alpha_stretch), float(params.alpha_compress),
                         float(params.dt), int(params.n_sub), int(params.n_iter))
    if not use:
        _frame_numpy(state, targets, edges, tethers, samples, body, params)
        return
    if scratch is None:
        scratch = make_scratch(len(edges.pairs), len(state.v), len(state.x), len(samples.pairs))
    _frame_loop(state, targets, edges, tethers, samples, body, params, scratch)
