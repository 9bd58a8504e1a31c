"""Layers between items: which item lies over which on the reference, and
the pass that keeps outer layers over the items under them on a target
(plain numpy; lengths in metres).

- :func:`layer_pairs`, :func:`layer_order`: the item-level order on the
  reference (outer item, inner item, separation to keep);
- :func:`layer_gaps`: the per-vertex separations and inner partners of that
  order, measured on the reference;
- :func:`keep_layers`: push outer-layer vertices out along the body normal
  until they clear the item under them again.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..geometry.closest import SurfaceQuery
from ..model import Mesh

LAYER_RADIUS = 0.03   # m: items closer than this may lie over one another
# m: separation kept between layers (or their reference gap if smaller): covers the sag of a coarse outer
# layer between its vertices
LAYER_MIN_GAP = 0.005


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
                radius: float = LAYER_RADIUS, min_pairs: int = 20):
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
