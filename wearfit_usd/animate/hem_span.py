"""Whether a skirt's hem can go round the legs: a narrow hem in a wide stride.

A straight skirt to the ankles has a hem about as long as the outline of
two ankles side by side. In a full stride, a lunge or a wide stance the
legs at that height are farther apart than the hem is long: cloth that
stretches at most ``SLACK`` (the strain limit's 1.1x) cannot surround them
there, so the hem rides up the legs until their outline fits, and the
shins show. That is what the motion measures then report as coverage loss
(the long skirt in CMU 131_01's wide stance: 23 %). It is the garment
against the clip, not a fault of the dressing; this says so, with the
frames and the heights.

Per frame, on the posed body: the hem's height at rest measured down from
the crotch (the lowest torso vertex; the skirt hangs from the hips), the
leg vertices within ``SLAB`` of that height projected on the floor plane,
and the perimeter of their convex hull (the shortest loop round both legs)
against the hem's length in the static dress:

    outline(frame) > SLACK * hem  ->  the hem cannot stay at its height.

Arrays are numpy; metres, y up.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ..geometry.mesh import boundary_loops

SLACK = 1.1     # x: the most the cloth's edges may stretch (strain_limit.LIMIT)
SLAB = 0.02     # m: half the height of the slice of the legs at the hem's height


def outline(points: np.ndarray) -> float:
    """Perimeter of the convex hull of (P, 2) points (0 with fewer than 3
    or all on a line)."""
    if len(points) < 3:
        return 0.0
    try:
        return float(ConvexHull(points).area)   # in 2D scipy's "area" is the perimeter
    except QhullError:
        return 0.0


class HemSpan:
    """``span(body) -> outline (m)``: the legs' outline at the hem's height
    on a posed body (N, 3) (module docstring); :attr:`hem` its static
    length.

    Parameters
    ----------
    item_points : (M, 3) the skirt dressed statically (bind pose).
    item_faces : (F, 3) int.
    body0 : (N, 3) the body of that dress.
    legs, torso : (N,) bool, the body's leg and torso vertices.
    """

    def __init__(self, item_points: np.ndarray, item_faces: np.ndarray, body0: np.ndarray,
                 legs: np.ndarray, torso: np.ndarray):
        p = np.asarray(item_points, dtype=np.float64)
        b = np.asarray(body0, dtype=np.float64)
        self.legs = np.flatnonzero(np.asarray(legs, dtype=bool))
        self.torso = np.flatnonzero(np.asarray(torso, dtype=bool))
        if len(self.legs) == 0 or len(self.torso) == 0:
            raise ValueError("HemSpan needs leg and torso vertices")
        loops = boundary_loops(item_faces)
        if not loops:
            raise ValueError("the skirt has no boundary: no hem")
        self.loop = min(loops, key=lambda lp: float(p[lp, 1].mean()))   # the lowest: the hem
        ring = p[self.loop]
        self.hem = float(np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1).sum())
        # how far the hem hangs below the crotch at rest
        self.drop = float(b[self.torso, 1].min() - ring[:, 1].mean())
        self.height0 = float(ring[:, 1].mean() - b[self.legs, 1].min())   # over the floor at rest

    def height(self, body: np.ndarray) -> float:
        """The hem's height at rest on ``body`` (N, 3): its drop below the crotch."""
        return float(np.asarray(body)[self.torso, 1].min()) - self.drop

    def __call__(self, body: np.ndarray) -> float:
        b = np.asarray(body)
        legs = b[self.legs]
        near = np.abs(legs[:, 1] - self.height(b)) <= SLAB
        return outline(legs[near][:, [0, 2]])


def narrow_frames(spans: np.ndarray, hem: float, slack: float = SLACK) -> np.ndarray:
    """Indices of the frames whose legs' outline ``spans`` (F,) the hem
    (length ``hem``) cannot go round, stretched ``slack`` at most."""
    return np.flatnonzero(np.asarray(spans) > slack * hem)
