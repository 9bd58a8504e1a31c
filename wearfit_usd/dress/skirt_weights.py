"""Skin weights for the skirt parts of dressed items: each side its own side's skin.

The dress plan binds a skirt's hanging part to the hips (:mod:`regions`:
``HIPS``, so that the redress never pulls one vertex with both legs), and the
per-frame redress lets it hang as cloth (:mod:`animate.cloth`). A skinned
copy (:func:`item_weights.skinned_items`, for engines) has no cloth: with the
hips' weights of that binding it moved with the pelvis alone and the legs
came through it in every stride (``ref_female_longskirt``'s skirt on the 10
dev targets, CMU walk: 9.9-21 % new penetrations against the redress's
0.3-1.7 %).

Here a skirt-part vertex ``p`` (bind pose) takes the skin weights of the body
under it on its own side, as far as the legs' swing can reach it. With
``h_l, h_r`` the hip joints (the thighs' roots), ``m`` their middle, ``a =
h_l - h_r`` and ``e`` the thighs' mean direction (:class:`Hips`):

* lateral position ``u = (p - m) . a / |a|^2`` (+-1/2 over the hip joints);
  the left side's part ``l = smoothstep(1/2 + g u)`` (``SIDE_GAIN``);
* ``W_k(p)``, ``d_k(p)`` (k = left, right): the skin weights at the closest
  point of side k's surface, the torso and that leg (the body triangles whose
  weight is mostly the torso's or that leg's joints; not the other leg's, not
  the arms'), and the distance to it;
* the swing of a leg at the vertex's depth ``sigma = max(REACH (p - m) . e,
  SWING_MIN)`` and the vertex's farness from side k ``c_k = smoothstep((d_k /
  sigma - FAR[0]) / (FAR[1] - FAR[0]))``: 0 where the leg sweeps well past the
  cloth, 1 where it cannot reach it;
* ``W_k'``: ``W_k`` with the share ``c_k`` of the weight of the joints below
  the knee moved to the thigh (cloth far from the shin does not bend with the
  knee);

    w'(p) = (1 - k) (l W_l' + (1 - l) W_r') + k w(p),
    k = FAR_HIPS (l c_l + (1 - l) c_r)

with ``w(p)`` the hips' weights. So a narrow skirt moves as the skin of each
leg (thigh, knee and calf) and of the hips (as the top tucked under its
waistband is skinned), its middle blends both sides; a wide one's panels
follow the thighs half-way and keep their shape. Between the legs the cloth
stretches in a stride (a web, as any skinned skirt without bones of its own),
but the legs stay inside.

Measured, the skinned copy's worst new penetrations (CMU walk's first 60
frames at 30 fps, every 2nd frame; ``benchmarks/bench_skinned.py``):
``ref_female_longskirt`` on the 10 dev targets (the redress 0.28-1.67 %): the
hips' weights alone 9.9-21.4 % (0 of 10 within 1 point of the redress); a
ramp from them to the sides' skin from 0.1 m above the hip joints over 0.15 m:
each leg's skin alone (not the torso), ``g = 1``, 0.56-6.56 % (2 of 10); with
the torso, ``g = 1``, 0.56-5.73 % (2); ``g = 2``, 0.42-5.31 % (3); the
figures of this rule are in the README. On single shots (the long skirt on
body_female_heavy and body_male_muscular_heavy; the demo's A-line dress on
``tall_thin``, its flared skirt on ``short_heavy``; the redress 0.42, 1.12,
0.17, 0.69 %): the whole skirt on the sides' skin (no farness) 0.56, 4.61,
0.33, 0.09 %, but the dress's hem swung out with the calves and creased at
the knees (stretch p99 5.9x, the redress 1.1x); the calves' weight to the
thigh where far 0.70, 5.17, 0.83, 0.09 % (the dress's front panel swung
rigidly with the thigh, its hem past the toes); and half the hips where far
(this rule) 0.98, 4.05, 0.58, 0.35 % (stretch p99 3.8, 5.0, 3.1, 1.9x). The
farness measured from ``SWING_MIN`` 0.05 m instead of 0.15 m (the waistband
then "far") 7.71, 8.66, 0.62, 4.77 %; all of the weight to the hips by a
ramp of ``d / sigma`` over 0.3-0.7 (no calf to thigh) 2.24, 5.03, 3.18,
2.95 % (the dress as on the hips alone), over 0.5-1.2 with the calves' weight
to the thigh 0.70, 5.17, 1.82, 0.87 % (the dress waved: the pelvis in its
middle, the thigh at its hem). Body_female_heavy (15
frames): the thigh joints instead of the skin, below the hip joints over 0.25
m, 12.6 %; the skin over the same ramp 10.1 % (the buttocks, skinned partly
to the thighs, came through the skirt still on the hips). Tried, not kept
(body_male_cmu_rig / body_male_muscular_heavy, with the ramp): the weights
smoothed over the skirt after (5 or 20 steps of neighbour averaging) 2.92 /
5.31 % -> 4.46 / 5.73 % and 8.77 / 13.7 %; the torso only above the hip
joints, 2.92 / 6.01 %. What is left is the middle at the crotch's height (on
body_male_muscular_heavy 55 of the long skirt's 720 vertices inside in the
worst frame, 14 mm deep at the median): a blend of two legs' rotations cannot
follow the forward leg's inner thigh.

Arrays are numpy; internal space (Y up, metres, the character's left +x).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..geometry.closest import SurfaceQuery
from .corrections import smoothstep
from .regions import LEFT_LEG, RIGHT_LEG, TORSO, joint_regions, subtree, triangle_regions

#: the left side's part is smoothstep(1/2 + SIDE_GAIN u): at 2 the skirt is
#: wholly on one side's skin from halfway to the hip joint outward
SIDE_GAIN = 2.0
#: a leg's swing at depth s below the hip joints: REACH * s (a thigh's 30
#: degrees), at least SWING_MIN (m) (the waist and hips: their skin moves
#: the cloth whatever its swing)
REACH = 0.5
SWING_MIN = 0.15
#: the cloth's distance from a side's skin over that side's swing: up to
#: FAR[0] it follows the skin as it is, from FAR[1] on it is "far": the knee's
#: and calf's weights go to the thigh and FAR_HIPS of the weight to the hips
FAR = (0.2, 0.5)
FAR_HIPS = 0.5


@dataclass
class Hips:
    """The hips' frame of a skeleton in its bind pose (:func:`hip_axes`).

    middle: (3,) between the hip joints; lateral: (3,) ``a = h_l - h_r`` (not
    unit: ``u = (p - m) . a / |a|^2`` is +-1/2 over the hip joints); down:
    (3,) unit mean direction of the thighs; thighs: (2,) the hip joints
    (left, right); below_knee: (2, J) bool, each knee's subtree.
    """
    middle: np.ndarray
    lateral: np.ndarray
    down: np.ndarray
    thighs: np.ndarray
    below_knee: np.ndarray


def hip_axes(skeleton) -> Hips | None:
    """The hips' frame of a skeleton (:class:`Hips`), or None when it has no
    two legs.

    The legs are :func:`regions.joint_regions`' leg subtrees; on each the
    knee is the joint between the subtree's root and its foot (lowest joint)
    whose height is nearest their middle, the hip joint the knee's parent (a
    rig with a helper joint above the thigh keeps the thigh). Joint names are
    not used."""
    parents = np.asarray(skeleton.parents)
    labels = joint_regions(skeleton)
    pos = skeleton.bind_positions()
    thighs, knees = [], []
    for lab in (LEFT_LEG, RIGHT_LEG):
        leg = np.flatnonzero(labels == lab)
        if len(leg) < 2:
            return None
        chain = [int(leg[np.argmin(pos[leg, 1])])]  # foot up to the leg's root
        while parents[chain[-1]] >= 0 and labels[parents[chain[-1]]] == lab:
            chain.append(int(parents[chain[-1]]))
        if len(chain) < 2:
            return None
        mid_h = 0.5 * (pos[chain[0], 1] + pos[chain[-1], 1])
        knee = min(chain[1:-1] or chain[:1], key=lambda j: abs(pos[j, 1] - mid_h))
        knees.append(knee)
        thighs.append(int(parents[knee]))
    hips, kp = pos[thighs], pos[knees]
    lateral = hips[0] - hips[1]
    down = (kp - hips).sum(axis=0)
    norm = float(np.linalg.norm(down))
    if lateral @ lateral < 1e-12 or norm < 1e-9:
        return None
    return Hips(hips.mean(axis=0), lateral, down / norm, np.array(thighs),
                np.array([subtree(parents, k) for k in knees]))


def has_leg_skin(labels: np.ndarray) -> bool:
    """Whether both legs hold most of the weight of some body vertices,
    (N,) ``labels`` their regions (:func:`regions.vertex_regions`): a
    :class:`LegSkin` can be built."""
    return bool((labels == LEFT_LEG).any() and (labels == RIGHT_LEG).any())


class LegSkin:
    """The skin weights of each side's surface (the torso and one leg),
    queried at its closest point.

    Built once per body: ``LegSkin(points, faces, body_w, labels)``, then
    ``leg_skin.weights(query)`` -> ``((W_left, W_right), (d_left, d_right))``.

    Parameters
    ----------
    points : (N, 3) array
        The body in the bind pose (the topology ``faces`` index).
    faces : (T, 3) int array
    body_w : (N, J) scipy.sparse matrix
        The body's skin weights (:func:`item_weights.weight_matrix`).
    labels : (N,) int array
        Each body vertex's region (:func:`regions.vertex_regions`: the one
        whose joints carry most of its weight): they say which triangles are
        torso and which each leg.
    """

    def __init__(self, points: np.ndarray, faces: np.ndarray, body_w: sp.csr_matrix, labels: np.ndarray):
        points = np.asarray(points, dtype=np.float64)
        faces = np.asarray(faces, dtype=np.int64)
        if body_w.shape[0] != len(points):
            raise ValueError(f"body weights for {body_w.shape[0]} vertices, body of {len(points)}")
        if len(labels) != len(points):
            raise ValueError(f"region labels for {len(labels)} vertices, body of {len(points)}")
        tri = triangle_regions(faces, np.asarray(labels))
        self.body_w = body_w.tocsr()
        self.sides = []
        for lab in (LEFT_LEG, RIGHT_LEG):
            if not (tri == lab).any():
                raise ValueError("the body has no triangles skinned mostly to a leg")
            f = faces[(tri == lab) | (tri == TORSO)]
            self.sides.append((SurfaceQuery(f, points), f))

    def weights(self, query: np.ndarray) -> tuple:
        """``((W_left, W_right), (d_left, d_right))``: (P, J) skin weights at
        each (P, 3) query point's closest point on each side (barycentric
        blend, rows sum to 1) and the (P,) distances to it."""
        query = np.asarray(query, dtype=np.float64)
        m, n = len(query), self.body_w.shape[0]
        out, dist = [], []
        for q, faces in self.sides:
            # the side's triangles only: the full body's vertex rings would reach off them
            res = q.closest(query, ring=False)
            bary = np.clip(res["bary"], 0.0, 1.0)
            bary /= np.maximum(bary.sum(axis=1, keepdims=True), 1e-12)
            c = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(m), 3), faces[res["triangle"]].ravel())),
                              shape=(m, n))
            out.append((c @ self.body_w).toarray())
            dist.append(np.abs(res["distance"]))
        return tuple(out), tuple(dist)


def skirt_weights(hip_weights: np.ndarray, points: np.ndarray, hips: Hips, side_weights: tuple,
                  side_distances: tuple, side_gain: float = SIDE_GAIN, reach: float = REACH,
                  swing_min: float = SWING_MIN, far: tuple = FAR, far_hips: float = FAR_HIPS) -> np.ndarray:
    """Skirt-part weights (module docstring).

    Parameters
    ----------
    hip_weights : (P, J) array
        The vertices' weights from their binding to the hips.
    points : (P, 3) array
        The vertices in the bind pose.
    hips : Hips
        :func:`hip_axes` of the skeleton.
    side_weights, side_distances : ((P, J), (P, J)), ((P,), (P,)) arrays
        Each side's skin weights under each vertex and the distance to that
        side's skin (:meth:`LegSkin.weights`).
    side_gain, reach, swing_min, far, far_hips : float
        ``SIDE_GAIN``, ``REACH``, ``SWING_MIN``, ``FAR`` (a pair),
        ``FAR_HIPS``.

    Returns
    -------
    (P, J) array, rows summing to 1.
    """
    p = np.asarray(points, dtype=np.float64)
    w0 = np.asarray(hip_weights, dtype=np.float64)
    sides = [np.array(x, dtype=np.float64) for x in side_weights]
    dists = [np.asarray(x, dtype=np.float64) for x in side_distances]
    if (p.ndim != 2 or p.shape[1] != 3 or w0.shape[0] != len(p)
            or any(x.shape != w0.shape for x in sides) or any(x.shape != (len(p),) for x in dists)):
        raise ValueError(f"skirt points {p.shape}, hip weights {w0.shape}, side weights "
                         f"{[x.shape for x in sides]}, distances {[x.shape for x in dists]}: expected (P, 3), "
                         "(P, J), (P, J) twice and (P,) twice")
    if side_gain <= 0 or reach <= 0 or swing_min <= 0 or not 0 <= far[0] < far[1] or not 0 <= far_hips <= 1:
        raise ValueError(f"skirt parameters side_gain {side_gain}, reach {reach}, swing_min {swing_min}, "
                         f"far {far}, far_hips {far_hips}: expected positive, far[0] < far[1], far_hips in [0, 1]")
    rel = p - hips.middle
    left = smoothstep(0.5 + side_gain * rel @ hips.lateral / float(hips.lateral @ hips.lateral))
    swing = np.maximum(reach * (rel @ hips.down), swing_min)
    farness = []
    for w, d, thigh, below in zip(sides, dists, hips.thighs, hips.below_knee):
        c = smoothstep((d / swing - far[0]) / (far[1] - far[0]))
        moved = w[:, below].sum(axis=1) * c   # far from the leg: the knee's bend does not reach it
        w[:, below] *= (1.0 - c)[:, None]
        w[:, thigh] += moved
        farness.append(c)
    out = left[:, None] * sides[0] + (1.0 - left)[:, None] * sides[1]
    k = far_hips * (left * farness[0] + (1.0 - left) * farness[1])
    out = (1.0 - k)[:, None] * out + k[:, None] * w0
    return out / np.maximum(out.sum(axis=1, keepdims=True), 1e-12)
