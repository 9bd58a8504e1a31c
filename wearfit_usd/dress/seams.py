"""Where an item crosses from one body region to another: blend shares.

The dress plan binds each item vertex within one body region (:mod:`regions`):
a sleeve to the arm, the jacket it is sewn to to the torso, a collar to the
torso, the hair on the scalp to the head. At the line where the region
changes, two neighbouring vertices then follow different body parts: when
the arm goes up the sleeve goes with it and the jacket stays, and the edges
across the line tear open (a one-piece suit's armholes stretched 20x with
the arms lowered from the A-pose, 37x after a raise). The body does not tear
there because its skin weights blend the shoulder and the spine over a band.

:func:`seam_shares` gives the item the same kind of band: each vertex within
``band`` (measured along the item's own edges) of a vertex bound to another,
adjacent region gets a share of that region,

    phi_L(v) = (1 - D_L(v) / band)_+ ** 2,    share_L(v) = phi_L(v) / sum_L' phi_L'(v),

with ``D_L(v)`` the shortest path along the item's edges from ``v`` to a
vertex of label ``L`` (0 for its own label). Kept are the vertex's own label
and the one other label with the largest share. The plan binds such a
vertex to the nearest triangles of both regions and blends the two bindings
by these shares (:func:`binding.blend_rows`): one sparse row still, smooth
across the line, exact on the body it was built on.

Only regions that meet on the body blend (torso with arms, legs, head; the
hips a skirt hangs from with the torso above them; the two legs, in the
crotch, over a narrower band: :data:`PAIR_BAND`); a skirt next to a hand
does not.

Arrays are numpy; lengths in metres.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from . import regions as R

SEAM_BAND = 0.08  # m along the item: half-width of the blend across a region line

#: label pairs that meet on the body (HIPS: the skirt label, torso triangles the legs do not move)
ADJACENT = {frozenset(p) for p in [(R.TORSO, R.LEFT_ARM), (R.TORSO, R.RIGHT_ARM), (R.TORSO, R.HEAD),
                                   (R.TORSO, R.LEFT_LEG), (R.TORSO, R.RIGHT_LEG), (R.HIPS, R.TORSO),
                                   (R.HIPS, R.LEFT_ARM), (R.HIPS, R.RIGHT_ARM), (R.HIPS, R.HEAD),
                                   (R.LEFT_LEG, R.RIGHT_LEG)]}

#: the band of a pair narrower than the item's (m along the item): the two
#: legs meet only in the crotch, where trousers and pants join them in one
#: seam; there the sides blend over a short band (the gusset), while a
#: trouser leg's inside a few centimetres below it follows its own leg only
PAIR_BAND = {frozenset((R.LEFT_LEG, R.RIGHT_LEG)): 0.03}


def label_distances(points: np.ndarray, item_edges: np.ndarray, labels: np.ndarray, band: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Shortest path along the item's edges from every vertex to the
    nearest vertex of each label, up to ``band``.

    Parameters
    ----------
    points : (M, 3) item vertices.
    item_edges : (E, 2) their edges.
    labels : (M,) int region label per vertex.
    band : float, the largest distance searched (farther: inf).

    Returns
    -------
    present : (L,) the labels present, sorted.
    dist : (M, L) distances (inf beyond ``band``).
    """
    m = len(points)
    present = np.unique(labels)
    dist = np.full((m, len(present)), np.inf)
    e = np.asarray(item_edges, dtype=np.int64)
    if len(e) == 0 or len(present) < 2:
        dist[np.arange(m), np.searchsorted(present, labels)] = 0.0
        return present, dist
    length = np.maximum(np.linalg.norm(points[e[:, 0]] - points[e[:, 1]], axis=1), 1e-12)
    # a super-source per label: one Dijkstra from it reaches every vertex of
    # the label at distance 0 (row m of the graph, rebuilt per label)
    base = sp.coo_matrix((length, (e[:, 0], e[:, 1])), shape=(m + 1, m + 1))
    for j, lab in enumerate(present):
        src = np.flatnonzero(labels == lab)
        link = sp.coo_matrix((np.full(len(src), 1e-12), (np.full(len(src), m), src)), shape=(m + 1, m + 1))
        g = (base + link).tocsr()
        d = dijkstra(g, directed=False, indices=m, limit=band)
        dist[:, j] = np.where(labels == lab, 0.0, d[:m])
    return present, dist


def seam_shares(points: np.ndarray, item_edges: np.ndarray, labels: np.ndarray, band: float = SEAM_BAND
                ) -> tuple[np.ndarray, np.ndarray]:
    """The other region each item vertex blends with, and its share (module docstring).

    Parameters
    ----------
    points : (M, 3) item vertices; item_edges (E, 2); labels (M,) binding
        labels (:mod:`regions`, HIPS for skirt parts).
    band : float, metres along the item.

    Returns
    -------
    other : (M,) int, the other label (-1: none).
    share : (M,) float in [0, 1/2], the weight of ``other``'s binding.
    """
    labels = np.asarray(labels, dtype=np.int64)
    m = len(labels)
    other = np.full(m, -1, dtype=np.int64)
    share = np.zeros(m)
    if m == 0 or band <= 0:
        return other, share
    present, dist = label_distances(np.asarray(points, dtype=np.float64), item_edges, labels, band)
    if len(present) < 2:
        return other, share
    # only regions that meet the vertex's own region on the body, over the
    # pair's band (PAIR_BAND, at most ``band``)
    pair = [[frozenset((int(a), int(b))) for b in present] for a in present]
    ok = np.array([[p in ADJACENT for p in row] for row in pair])
    width = np.array([[min(band, PAIR_BAND.get(p, band)) for p in row] for row in pair])
    own = np.searchsorted(present, labels)
    phi = np.clip(1.0 - dist / width[own], 0.0, None) ** 2
    phi = np.where(ok[own], phi, 0.0)
    phi[np.arange(m), own] = 1.0
    rival = phi.copy()
    rival[np.arange(m), own] = 0.0
    best = np.argmax(rival, axis=1)
    top = rival[np.arange(m), best]
    has = top > 1e-6
    other[has] = present[best[has]]
    share[has] = top[has] / (1.0 + top[has])
    return other, share
