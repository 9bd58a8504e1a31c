"""Layers between items: which item lies over which on the reference, and
the pass that keeps outer layers over the items under them on a target
(plain numpy; lengths in metres).

- :func:`layer_pairs`, :func:`layer_order`: the item-level order on the
  reference (outer item, inner item, separation to keep);
- :func:`layer_gaps`: the per-vertex separations and inner partners of that
  order, measured on the reference;
- :func:`under_skirts`: the parts of other items a skirt encloses (shorts
  under a skirt, whatever the reference's interleaving) put under it;
- :func:`keep_layers`: push outer-layer vertices out along the body normal
  until they clear the item under them again.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..geometry.closest import SurfaceQuery
from ..geometry.mesh import components, edges
from ..model import Mesh

LAYER_RADIUS = 0.03   # m: items closer than this may lie over one another
# m: separation kept between layers (or their reference gap if smaller): covers the sag of a coarse outer
# layer between its vertices
LAYER_MIN_GAP = 0.005
#: close vertex pairs an item (:func:`layer_order`) or a part of one
#: (:func:`under_skirts`) needs to lie over another
MIN_PAIRS = 20
#: m: a connected part of another item whose top lies at least this far
#: below a skirt's top is enclosed by the skirt (:func:`under_skirts`)
ENCLOSED_BELOW = 0.01
#: m: the least separation a skirt keeps over the parts it encloses
ENCLOSED_GAP = 0.003


def layer_pairs(items: list[Mesh], offsets: np.ndarray, points: np.ndarray, clearance: np.ndarray,
                radius: float = LAYER_RADIUS):
    """Which item lies over which, on the reference.

    For every vertex of every item, the nearest vertex of each *other* item
    within ``radius``; kept where this vertex is farther from the body (by
    more than 0.5 mm): it is the outer layer there. Returns (outer (P,),
    inner (P,), gap (P,)) indices into the stacked points and the reference
    clearance difference (m)."""
    outer, inner, gap = [], [], []
    trees = [cKDTree(points[a:b]) for a, b in zip(offsets[:-1], offsets[1:])]
    for i, (a, b) in enumerate(zip(offsets[:-1], offsets[1:])):
        for j, c in enumerate(offsets[:-1]):
            if i == j:
                continue
            dist, near = trees[j].query(points[a:b], k=1, distance_upper_bound=radius)
            ok = np.isfinite(dist)
            o = np.flatnonzero(ok) + a
            n = near[ok] + c
            g = clearance[o] - clearance[n]
            keep = g > 0.0005
            outer.append(o[keep])
            inner.append(n[keep])
            gap.append(g[keep])
    if not outer:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(outer), np.concatenate(inner), np.concatenate(gap)


def layer_order(items: list[Mesh], offsets: np.ndarray, points: np.ndarray, clearance: np.ndarray,
                radius: float = LAYER_RADIUS, min_pairs: int = MIN_PAIRS):
    """Item-level layer order on the reference: [(outer item, inner item,
    separation to keep (m))] for every pair of items that overlap, the outer
    one being farther from the body at most of their close vertex pairs. The
    separation is the median reference gap, capped at ``LAYER_MIN_GAP``."""
    outer, inner, gap = layer_pairs(items, offsets, points, clearance, radius)
    item_of = np.searchsorted(offsets, np.arange(len(points)), side="right") - 1
    order = []
    n = len(items)
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            sel = (item_of[outer] == i) & (item_of[inner] == j)
            rev = int(np.sum((item_of[outer] == j) & (item_of[inner] == i)))
            if sel.sum() >= min_pairs and sel.sum() > 2 * rev:
                order.append((i, j, float(min(np.median(gap[sel]), LAYER_MIN_GAP))))
    return order


def _under(foot: np.ndarray, offsets: np.ndarray, j: int, oi: np.ndarray, radius: float):
    """The vertex of item ``j`` over the same spot of the body as each outer
    vertex ``oi`` (stacked indices): the one whose footprint (closest body
    point, foot (M, 3)) is nearest, if within ``radius``. Returns (found
    (len(oi),) bool, stacked indices of those found)."""
    ij = np.arange(offsets[j], offsets[j + 1])
    d, k = cKDTree(foot[ij]).query(foot[oi], k=1, distance_upper_bound=radius)
    ok = np.isfinite(d)
    return ok, ij[k[ok]]


def keep_layers(query: SurfaceQuery, pts: np.ndarray, offsets: np.ndarray, order: list,
                radius: float = 0.02, mask: np.ndarray | None = None, footprints: dict | None = None):
    """Push outer-layer vertices out along the body normal until they clear
    the item under them by the separation of :func:`layer_order`, or by the
    per-vertex separation of :func:`layer_gaps` when an entry of ``order``
    carries an array (one value per vertex of its outer item) instead of a
    number.

    Both layers are compared over the same spot of the body: every vertex's
    closest body point is its footprint, and an outer vertex is checked
    against the inner item's vertex with the nearest footprint (within
    ``radius``), or against the inner vertex an entry of ``order`` names for
    it (a fourth element: stacked indices (n_outer,), -1 for none, as
    :func:`layer_gaps` pairs them on the reference). Clearance to the body
    serves as the height, which works for open garments.
    mask: (M,) bool, the only vertices that may be pushed (default all).
    footprints: {"distance" (M,), "point" (M, 3), "normal" (M, 3)}: the
        closest body points of ``pts`` when already known (e.g. refreshed for
        the few vertices that moved); default: queried for all.
    Returns (points, moved (M,) bool)."""
    moved = np.zeros(len(pts), dtype=bool)
    if not order:
        return pts, moved
    res = query.closest(pts) if footprints is None else footprints
    c, foot, nrm = res["distance"], res["point"], res["normal"]
    push = np.zeros(len(pts))
    for i, j, sep, *pairs in order:
        oi = np.arange(offsets[i], offsets[i + 1])
        if mask is not None:
            oi = oi[mask[oi]]
            if len(oi) == 0:
                continue
        if pairs:  # the inner vertex of each outer one, fixed on the reference
            under = pairs[0][oi - offsets[i]]
            ok = under >= 0
            under = under[ok]
        else:
            ok, under = _under(foot, offsets, j, oi, radius)
        if np.ndim(sep):
            sep = np.asarray(sep)[oi[ok] - offsets[i]]
        need = sep - (c[oi[ok]] - c[under])
        np.maximum.at(push, oi[ok], np.where(need > 1e-4, need, 0.0))
    sel = np.flatnonzero(push > 0)
    if len(sel) == 0:
        return pts, moved
    nn = nrm[sel] / np.maximum(np.linalg.norm(nrm[sel], axis=1, keepdims=True), 1e-12)
    out = pts.copy()
    out[sel] += push[sel, None] * nn
    moved[sel] = True
    return out, moved


def layer_gaps(query: SurfaceQuery, points: np.ndarray, offsets: np.ndarray, order: list,
               clearance: np.ndarray, radius: float = 0.02, foot: np.ndarray | None = None) -> list:
    """Per-vertex separations for :func:`keep_layers`, measured on the reference.

    query: the reference body; points (M, 3): the reference items, stacked;
    clearance (M,): their signed distances to that body (m); order: the
    item-level [(outer, inner, separation)] of :func:`layer_order`.
    Every vertex of an outer item keeps the item-level separation, or the gap
    it had on the reference if that was smaller, measured the way
    :func:`keep_layers` measures it (the inner vertex with the nearest
    footprint within ``radius``): a trouser hem that lay 2 mm over, or
    already inside, a shoe collar on the reference keeps that relation
    instead of being lifted 5 mm over the collar. So the layer pass leaves
    the reference unchanged on its own body. The inner vertex found for each
    outer one is kept with the gaps: on a target the pass compares the same
    pair. Searching again there could pick another sheet of the inner item
    over the same spot (a lapel over the shirt front), whose vertices lie
    farther out, and lift the outer vertex over that sheet instead (20-28 mm
    on a layer 4 mm over ref_male's suit).
    foot: (M, 3) the closest body points of ``points`` if already known.
    Returns [(outer, inner, separation (n_outer,) m, inner vertex of each
    outer vertex (n_outer,) stacked index or -1)].
    """
    if not order:
        return []
    if foot is None:
        foot = query.closest(points)["point"]
    out = []
    for i, j, sep in order:
        oi = np.arange(offsets[i], offsets[i + 1])
        ok, under = _under(foot, offsets, j, oi, radius)
        gap = np.full(len(oi), float(sep))
        gap[ok] = np.minimum(sep, clearance[oi[ok]] - clearance[under])
        pair = np.full(len(oi), -1, dtype=np.int64)
        pair[ok] = under
        out.append((i, j, gap, pair))
    return out


def _highest_within(foot: np.ndarray, clearance: np.ndarray, outer: np.ndarray, inner: np.ndarray,
                    reach) -> tuple[np.ndarray, np.ndarray]:
    """For each outer vertex (stacked indices (P,)), the inner vertex (of
    ``inner`` (Q,)) farthest from the body among those whose footprint lies
    within ``reach`` (scalar or (P,)) of its own. Returns (positions into
    ``outer`` that have one, their inner vertices)."""
    lists = cKDTree(foot[inner]).query_ball_point(foot[outer], r=reach)
    counts = np.fromiter((len(v) for v in lists), dtype=np.int64, count=len(outer))
    if not counts.any():
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    rows = np.repeat(np.arange(len(outer)), counts)
    cand = inner[np.concatenate([np.asarray(v, dtype=np.int64) for v in lists if len(v)])]
    by = np.lexsort((-clearance[cand], rows))          # per row, the highest first
    first = np.r_[True, rows[by][1:] != rows[by][:-1]]
    return rows[by][first], cand[by][first]


def under_skirts(layers: list, items: list[Mesh], offsets: np.ndarray, points: np.ndarray,
                 clearance: np.ndarray, foot: np.ndarray, skirts: list, fixed: np.ndarray | None = None,
                 radius: float = 0.02, below: float = ENCLOSED_BELOW, gap: float = ENCLOSED_GAP,
                 over_gap: float = LAYER_MIN_GAP) -> list:
    """:func:`layer_gaps`' per-vertex order with every skirt over the parts
    of other items it encloses, and under the parts found over it.

    The item-level order takes one item over another where most of their
    close vertex pairs say so, and the per-vertex gaps then keep the
    reference's interleaving. An asset can interleave what no garment does:
    in ``ref_female_longskirt.usda`` 635 of the 1,122 vertices of
    ``female_casualsuit02`` within 2 cm of the skirt stand out of it by up
    to 16 mm (the hot pants' hips and pockets), the top's hem and the
    skirt's waistband cross each other, and the suit, one mesh of a top and
    hot pants, comes out over the skirt: the pants showed through the skirt
    on every body and in every frame. Here, per connected part of another
    item (its faces' components):

    - a part whose top lies at least ``below`` under the skirt's top (the
      reference in its rest pose; Y up) is *enclosed*: each skirt vertex
      keeps at least ``gap`` over the highest vertex of those parts whose
      footprint lies within its longest edge (at most 3 ``radius``; a
      coarse skirt's vertices lie 4 cm apart, and a pocket between two of
      them came through their flat triangle), and the part no longer keeps
      its gap over the skirt;
    - a part that reaches higher and lies farther out than the skirt's
      nearest vertex at most of its close vertex pairs (at least
      ``MIN_PAIRS``, twice the reverse; a top whose hem hangs over the
      waistband) keeps at least ``over_gap`` over the highest skirt vertex within
      the skirt's median longest edge at a vertex (at least ``radius``; the
      spot parts are compared over): no strip of waistband through the hem.
      Per part, not per item: an item with a rigid piece (a suit's belt) is
      no outer layer in :func:`layer_order`'s list.

    Parameters
    ----------
    layers : list
        :func:`layer_gaps`' [(outer, inner, gaps (n_outer,), inner vertex
        of each outer vertex (n_outer,), -1 for none)].
    items : list of Mesh; offsets : (I + 1,) their stacked ranges.
    points : (M, 3) the items on the reference, stacked; clearance (M,)
        their signed distances to its body; foot (M, 3) their closest body
        points.
    skirts : names of the skirt items (:class:`plan.ItemRegions`).
    fixed : (M,) bool, optional
        Vertices never lifted over a skirt (rigid pieces move as a whole).
    radius : m, the least reach of "over the same spot".
    below : m, how far under the skirt's top an enclosed part's top lies.
    gap, over_gap : m, the least separation of the skirt over an enclosed
        part, and of a part over the skirt (5 mm as :data:`LAYER_MIN_GAP`:
        with 3 mm the walk on ``body_female_heavy`` had the skirt's
        waistband out through the top's hem at 21.7 % of the skirt vertices
        under the hem (median frame), 18.0 % with 5 mm).

    Returns
    -------
    list
        ``layers`` with the (skirt, item) and (item, skirt) entries made or
        replaced.
    """
    names = [m.name for m in items]
    out = [tuple(e) for e in layers]
    skirt_rows = [names.index(n) for n in skirts if n in names]
    parts = [components(m.faces, m.n_points) for m in items] if skirt_rows else []
    for s in skirt_rows:
        si = np.arange(offsets[s], offsets[s + 1])
        top = float(points[si, 1].max())
        tree = cKDTree(foot[si])
        # each skirt vertex's reach: its longest edge (at most 3 radius)
        ed = edges(items[s].faces)
        length = np.linalg.norm(points[si[ed[:, 0]]] - points[si[ed[:, 1]]], axis=1)
        reach = np.zeros(len(si))
        np.maximum.at(reach, ed[:, 0], length)
        np.maximum.at(reach, ed[:, 1], length)
        reach = np.minimum(reach, 3.0 * radius)
        spot = max(radius, float(np.median(reach)))   # "over the same spot" of the skirt
        for x, part in enumerate(parts):
            if x == s:
                continue
            xi = np.arange(offsets[x], offsets[x + 1])
            tops = np.full(part.max() + 1, -np.inf)
            np.maximum.at(tops, part, points[xi, 1])
            dist, nearest = tree.query(foot[xi], k=1, distance_upper_bound=spot)
            near = np.isfinite(dist)
            touching = np.isin(part, np.unique(part[near]))
            enclosed = touching & (tops[part] <= top - below)
            have = {(o, i): n for n, (o, i, *_) in enumerate(out)}
            if enclosed.any():
                g = np.full(len(si), LAYER_MIN_GAP)
                pair = np.full(len(si), -1, dtype=np.int64)
                if (s, x) in have:
                    _, _, g0, p0 = out[have[(s, x)]]
                    g, pair = np.asarray(g0, dtype=np.float64).copy(), np.asarray(p0).copy()
                rows, under = _highest_within(foot, clearance, si, xi[enclosed], reach)
                g[rows] = np.maximum(np.minimum(LAYER_MIN_GAP, clearance[si[rows]] - clearance[under]), gap)
                pair[rows] = under
                if (s, x) in have:
                    out[have[(s, x)]] = (s, x, g, pair)
                else:
                    out.append((s, x, g, pair))
                    have[(s, x)] = len(out) - 1
            # the parts reaching higher that lie over the skirt at most of
            # their close vertex pairs (per part: an item with a rigid piece,
            # a suit's belt, is no outer layer in the item-level order)
            ok = near & touching & ~enclosed
            if fixed is not None:
                ok &= ~np.asarray(fixed)[xi]
            d = clearance[xi[ok]] - clearance[si[nearest[ok]]]
            n_part = part.max() + 1
            ups = np.bincount(part[ok], weights=d > 0.0005, minlength=n_part)
            downs = np.bincount(part[ok], weights=d < -0.0005, minlength=n_part)
            over_part = (ups >= MIN_PAIRS) & (ups > 2 * downs)
            over = np.flatnonzero(ok & over_part[part])
            if len(over) == 0 and not (enclosed.any() and (x, s) in have):
                continue
            if (x, s) in have:
                _, _, g1, p1 = out[have[(x, s)]]
                g1 = np.asarray(g1, dtype=np.float64).copy()
                p1 = np.asarray(p1).copy()
            else:
                g1 = np.full(len(xi), LAYER_MIN_GAP)
                p1 = np.full(len(xi), -1, dtype=np.int64)
            if len(over):
                rows, under = _highest_within(foot, clearance, xi[over], si, spot)
                v = over[rows]
                g1[v] = np.maximum(np.minimum(LAYER_MIN_GAP, clearance[xi[v]] - clearance[under]), over_gap)
                p1[v] = under
            p1[enclosed] = -1          # the enclosed parts no longer kept over the skirt
            if (x, s) in have:
                out[have[(x, s)]] = (x, s, g1, p1)
            else:
                out.append((x, s, g1, p1))
    return out
