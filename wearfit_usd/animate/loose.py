"""Which item vertices hang loose in motion, and how freely: the cloth weight.

A loose part (a skirt below the hips, a dress, the tails of a long coat, a
cape, long hair) hangs from where it attaches to the body: the waistband,
the shoulders, the scalp. :func:`cloth_weights` gives every item vertex a
weight ``w`` in [0, 1] from the dress plan (:class:`redress.DressPlan`):

* ``w = 0``: attached, the vertex follows the binding exactly (tight parts,
  the attachment line and everything near it, rigid parts);
* ``w = 1``: free, the vertex is simulated (:mod:`animate.cloth`) and only
  loosely pulled toward its bound position;
* in between: a smooth ramp along the item surface, so the attachment is
  stiff near the attachment line and soft far from it.

The attachment line is where the item touches the body it hangs from. For a
skirt-like item (one the plan binds to the hips, ``plan.regions.skirt_items``) these
are its vertices within ``LOOSE_START`` of the body whose nearest body
triangle is torso and that lie ``HIP_HEIGHT`` above the crotch (the
waistband and the hips, not the thighs it also touches nor the groin the
thighs swing into). For other items they are its tight vertices (plan looseness 0:
within ``LOOSE_START`` of the body). With ``d`` the distance from the
attachment line measured along the item's edges (Dijkstra over the item mesh
at its reference shape),

    w = looseness * smoothstep((d - start) / ramp)

with ``start = 0`` for skirts (everything below the waistband hangs) and
``start = HANG_START`` for other items (a loose sleeve or a bob of hair a few
centimetres from its attachment is not cloth that swings: it stays bound),
``smoothstep(s) = 3 s^2 - 2 s^3`` on [0, 1]. The plan's looseness (0 for
parts within ``LOOSE_START`` of the body, 1 from ``LOOSE_FULL`` on; 1 on
skirts; 0 on rigid parts) caps the weight so tight parts never move freely.

Arrays are numpy; lengths in metres (internal space).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..dress import regions as R
from ..dress.corrections import LOOSE_START, smoothstep

SKIRT_RAMP = 0.12   # m along the skirt from its attachment line to fully free
HIP_HEIGHT = 0.10   # m above the crotch (lowest torso vertex) a skirt's attachment line starts
HIP_BAND = 0.08     # m: the band above that holding the attachment line (above it skirts stay bound)
HANG_START = 0.08   # m from the attachment line before other items start to hang free
HANG_RAMP = 0.10    # m over which they become fully free
MIN_FREE = 16       # an item with fewer vertices of weight > 0 is not simulated at all


def attachment_distance(points: np.ndarray, item_edges: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """(M,) shortest distance along the edges from any anchor vertex.

    points (M, 3); item_edges (E, 2); anchors (M,) bool. inf where no anchor
    is reachable (a separate piece that never touches the body)."""
    m = len(points)
    if not anchors.any():
        return np.full(m, np.inf)
    e = np.asarray(item_edges, dtype=np.int64)
    length = np.linalg.norm(points[e[:, 0]] - points[e[:, 1]], axis=1)
    length = np.maximum(length, 1e-9)  # zero-length edges are still edges for Dijkstra
    g = sp.csr_matrix((length, (e[:, 0], e[:, 1])), shape=(m, m))
    return dijkstra(g, directed=False, indices=np.flatnonzero(anchors), min_only=True)


def cloth_weights(plan, hang_start: float = HANG_START, detached: bool = False) -> np.ndarray:
    """(M,) cloth weight of every item vertex of ``plan`` (a
    :class:`redress.DressPlan`), 0 attached .. 1 free (see the module
    docstring). All zeros when the plan has no loose parts. ``hang_start``:
    the distance from the attachment line where items other than skirts
    start to hang (default ``HANG_START``); ``detached``: loose pieces that
    no path along the edges joins to an attachment (a ponytail's separate
    strands) hang fully (by default they stay bound as they are; the
    skinned copies' item joints take them, :mod:`item_joints`)."""
    m = len(plan.ref_points)
    w = np.zeros(m)
    if plan.looseness is None or plan.mesh.edges is None or not np.any(plan.looseness > 0):
        return w
    pts = np.asarray(plan.ref_points, dtype=np.float64)
    clear = np.asarray(plan.ref_clearance, dtype=np.float64)
    near_region = plan.regions.triangle[plan.ref_foot.triangle] if plan.ref_foot is not None else plan.regions.vertex
    skirt = plan.skirt_mask()
    tight = clear < LOOSE_START
    hips = near_region == R.TORSO
    below = np.ones(m, dtype=bool)   # skirt vertices that may hang (below the hip band)
    if plan.ref_body is not None and plan.regions.body is not None and np.any(plan.regions.body == R.TORSO):
        # not the groin: the thighs swing up into the skirt there
        crotch_y = float(np.min(np.asarray(plan.ref_body)[plan.regions.body == R.TORSO, 1]))
        hips &= pts[:, 1] > crotch_y + HIP_HEIGHT
        # a dress, a suit or a coat goes on above the hips: its top and its
        # sleeves (hanging beside the skirt, but joined to it only above the
        # band) stay bound; the band sits on the hips
        top = crotch_y + HIP_HEIGHT + HIP_BAND
        hips &= pts[:, 1] < top
        below = pts[:, 1] < top
    # the attachment line: the skirt's closest contact with the hips (an
    # item cut with some ease everywhere touches nowhere within LOOSE_START)
    for sl in plan.item_slices():
        band = skirt[sl] & hips[sl]
        if band.any():
            tight[sl] |= band & (clear[sl] < float(clear[sl][band].min()) + LOOSE_START)
    anchors = np.where(skirt, tight & hips, plan.looseness <= 0)
    e = np.asarray(plan.mesh.edges, dtype=np.int64)
    # skirts: distances within the part below the band (a sleeve hanging
    # beside the skirt is reached only through the shoulder: not at all)
    keep = ~skirt | below
    e = e[keep[e[:, 0]] & keep[e[:, 1]]]
    d = attachment_distance(pts, e, anchors & keep)
    # unattached pieces: bound as they are, or hanging fully (detached)
    d = np.where(np.isfinite(d), d, np.inf if detached else 0.0)
    w = np.where(skirt, smoothstep(d / SKIRT_RAMP), smoothstep((d - hang_start) / HANG_RAMP))
    w[skirt & ~below] = 0.0
    w *= plan.looseness
    w[plan.rigid_mask()] = 0.0
    for sl in plan.item_slices():
        if np.count_nonzero(w[sl]) < MIN_FREE:
            w[sl] = 0.0
    return w
