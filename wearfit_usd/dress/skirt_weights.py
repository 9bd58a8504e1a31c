"""Skin weights for the skirt parts of dressed items: from the hips to the legs.

The dress plan binds a skirt's hanging part to the hips (:mod:`regions`:
``HIPS``, so that the redress never pulls one vertex with both legs), and the
per-frame redress lets it hang as cloth (:mod:`animate.cloth`). A skinned
copy (:func:`item_weights.skinned_items`, for engines) has no cloth: with the
hips' weights alone it moved with the pelvis and the legs came through it in
every stride (``ref_female_longskirt``'s skirt on the 10 dev targets, CMU
walk: 9.9-21 % new penetrations against the redress's 0.3-1.7 %).

Here a skirt-part vertex ``p`` (bind pose) takes, below the hips, the skin
weights of the body under it on its own side. With ``h_l, h_r`` the hip
joints (the thighs' roots), ``m`` their middle, ``d`` the thighs' mean
direction (hip to knee) and ``a = h_l - h_r``:

* depth below the hip joints ``s = (p - m) . d``; the legs' share
  ``t = smoothstep((s - start) / ramp)`` (``SKIRT_START``, ``SKIRT_RAMP``);
* lateral position ``u = (p - m) . a / |a|^2`` (+-1/2 over the hip joints);
  the left side's part ``l = smoothstep(1/2 + g u)`` (``SIDE_GAIN``);
* ``W_l(p)``, ``W_r(p)``: the skin weights at the closest point of each
  side's surface, the torso and that leg (the body triangles whose weight is
  mostly the torso's or that leg's joints; not the other leg's, not the arms');

    w'(p) = (1 - t) w(p) + t (l W_l(p) + (1 - l) W_r(p))

so the skirt over each leg moves as the skin of that leg does (thigh, knee
and calf), over the hips and buttocks as the skin there does (as the top
tucked under the skirt is skinned), its middle blends both sides, its
waistband stays on the hips. Between the legs the cloth then stretches in a
stride (a web, as any skinned skirt without bones of its own), but the legs
stay inside it.

Measured: ``ref_female_longskirt`` on the 10 dev targets, the CMU walk's
first 60 frames at 30 fps, every 2nd frame (``benchmarks/bench_skinned.py``;
the skinned copy's worst new penetrations, the redress's 0.28-1.67 %): the
hips' weights alone 9.9-21.4 % (0 of 10 targets within 1 point of the
redress); each leg's skin alone (not the torso), ``g = 1``: 0.56-6.56 % (2);
with the torso, ``g = 1``: 0.56-5.73 % (2); ``g = 2``: 0.42-5.31 % (3). On
body_female_heavy (15 frames): the thigh joints instead of the skin
12.6 %; the ramp from the hip joints over 0.25 m 10.1 % (the buttocks,
skinned partly to the thighs, came through the skirt still on the hips), from
0.1 m above them over 0.15 m 2.1 %. The price is the web: the copies' edge
stretch p99 against the static dress, on body_male_cmu_rig and
body_male_muscular_heavy, 3.7-3.8x at ``g = 1`` and 5.6-6.2x at ``g = 2``
(the redress 1.2x); a narrower band stretches more. What is left is the
middle at the crotch's height (55 of the skirt's 720 vertices inside in the
worst frame on body_male_muscular_heavy, 14 mm deep at the median): a blend
of two legs' rotations cannot follow the forward leg's inner thigh. Tried,
not kept (body_male_cmu_rig / body_male_muscular_heavy, walk): the weights
smoothed over the skirt after (5 or 20 steps of neighbour averaging) 2.92 /
5.31 % -> 4.46 / 5.73 % and 8.77 / 13.7 % (stretch p99 6.2 -> 4.1 and 2.9x);
the torso only above the hip joints, 2.92 / 6.01 %.

Arrays are numpy; internal space (Y up, metres, the character's left +x).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..geometry.closest import SurfaceQuery
from .regions import LEFT_LEG, N_REGIONS, RIGHT_LEG, TORSO, joint_regions, triangle_regions

#: the legs' share starts this far (m) along the thighs below the hip joints
#: (negative: above them, where the buttocks already follow the thighs)
SKIRT_START = -0.10
#: and reaches all of the weight this far (m) below that
SKIRT_RAMP = 0.15
#: the left side's part is smoothstep(1/2 + SIDE_GAIN u): at 2 the skirt is
#: wholly on one side's skin from halfway to the hip joint outward
SIDE_GAIN = 2.0


def hip_axes(skeleton) -> tuple | None:
    """The hips' frame of a skeleton in its bind pose: ``(middle (3,),
    lateral (3,), down (3,))``, or None when it has no two legs.

    ``lateral`` is ``a = h_l - h_r`` (not unit: ``u = (p - m) . a / |a|^2``
    is +-1/2 over the hip joints), ``down`` the unit mean direction of the
    thighs. The legs are :func:`regions.joint_regions`' leg subtrees; on each
    the knee is the joint between the subtree's root and its foot (lowest
    joint) whose height is nearest their middle, the hip joint the knee's
    parent (a rig with a helper joint above the thigh keeps the thigh)."""
    parents = np.asarray(skeleton.parents)
    labels = joint_regions(skeleton)
    pos = skeleton.bind_positions()
    hips, knees = [], []
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
        hips.append(pos[parents[knee]])
        knees.append(pos[knee])
    hips, knees = np.array(hips), np.array(knees)
    down = (knees - hips).mean(axis=0)
    norm = np.linalg.norm(down)
    lateral = hips[0] - hips[1]
    if norm < 1e-9 or lateral @ lateral < 1e-12:
        return None
    return hips.mean(axis=0), lateral, down / norm


class LegSkin:
    """The skin weights of each leg's surface, queried at its closest point.

    Built once per body: ``LegSkin(points, faces, body_w, skeleton)``, then
    ``leg_skin.weights(query)`` -> ``(W_left, W_right)``, each (P, J).

    Parameters
    ----------
    points : (N, 3) array
        The body in the bind pose (the topology ``faces`` index).
    faces : (T, 3) int array
    body_w : (N, J) scipy.sparse matrix
        The body's skin weights (:func:`item_weights.weight_matrix`).
    skeleton : model.Skeleton
        Its joints' regions (:func:`regions.joint_regions`) say which
        triangles are legs (their vertices' weight mostly a leg's joints).
    """

    def __init__(self, points: np.ndarray, faces: np.ndarray, body_w: sp.csr_matrix, skeleton):
        points = np.asarray(points, dtype=np.float64)
        faces = np.asarray(faces, dtype=np.int64)
        if body_w.shape[0] != len(points):
            raise ValueError(f"body weights for {body_w.shape[0]} vertices, body of {len(points)}")
        jl = joint_regions(skeleton)
        share = (body_w @ sp.csr_matrix((np.ones(len(jl)), (np.arange(len(jl)), jl)),
                                        shape=(len(jl), N_REGIONS))).toarray()
        tri = triangle_regions(faces, np.argmax(share, axis=1))
        self.body_w = body_w.tocsr()
        self.legs = []
        for lab in (LEFT_LEG, RIGHT_LEG):
            if not (tri == lab).any():
                raise ValueError("the body has no triangles skinned mostly to a leg")
            f = faces[(tri == lab) | (tri == TORSO)]
            self.legs.append((SurfaceQuery(f, points), f))

    def weights(self, query: np.ndarray) -> tuple:
        """(W_left, W_right): (P, J) skin weights at each (P, 3) query
        point's closest point on each leg (barycentric blend, rows sum to 1)."""
        query = np.asarray(query, dtype=np.float64)
        m, n = len(query), self.body_w.shape[0]
        out = []
        for q, faces in self.legs:
            # the leg's triangles only: the full body's vertex rings would reach off them
            res = q.closest(query, ring=False)
            bary = np.clip(res["bary"], 0.0, 1.0)
            bary /= np.maximum(bary.sum(axis=1, keepdims=True), 1e-12)
            c = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(m), 3), faces[res["triangle"]].ravel())),
                              shape=(m, n))
            out.append((c @ self.body_w).toarray())
        return tuple(out)


def skirt_weights(weights: np.ndarray, points: np.ndarray, axes: tuple, leg_weights: tuple,
                  start: float = SKIRT_START, ramp: float = SKIRT_RAMP,
                  side_gain: float = SIDE_GAIN) -> np.ndarray:
    """Skirt-part weights carried from the hips to the legs (module docstring).

    Parameters
    ----------
    weights : (P, J) array
        The vertices' weights from their binding to the hips.
    points : (P, 3) array
        The vertices in the bind pose.
    axes : tuple
        :func:`hip_axes`: middle, lateral, down.
    leg_weights : ((P, J), (P, J)) arrays
        The left and right legs' skin weights under each vertex
        (:meth:`LegSkin.weights`).
    start, ramp : float
        Where (m below the hip joints) the legs' share starts, and over how
        far it reaches 1.
    side_gain : float
        ``g`` in the left side's part ``smoothstep(1/2 + g u)``.

    Returns
    -------
    (P, J) array, rows summing to 1.
    """
    w = np.asarray(weights, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    wl, wr = (np.asarray(x, dtype=np.float64) for x in leg_weights)
    if w.ndim != 2 or p.shape != (len(w), 3) or wl.shape != w.shape or wr.shape != w.shape:
        raise ValueError(f"skirt weights {w.shape}, points {p.shape}, leg weights {wl.shape}/{wr.shape}: "
                         "expected (P, J), (P, 3) and (P, J) twice")
    if ramp <= 0:
        raise ValueError(f"skirt ramp {ramp}: expected > 0")
    mid, lateral, down = axes
    t = _smoothstep(((p - mid) @ down - start) / ramp)
    left = _smoothstep(0.5 + side_gain * (p - mid) @ lateral / float(lateral @ lateral))
    out = (1.0 - t)[:, None] * w + (t * left)[:, None] * wl + (t * (1.0 - left))[:, None] * wr
    return out / np.maximum(out.sum(axis=1, keepdims=True), 1e-12)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)
