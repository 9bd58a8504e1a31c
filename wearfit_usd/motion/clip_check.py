"""How a clip lands on a body: feet on the floor, travel kept, joints paired.

The figures of issue 18's "any clip" checks, for tests and the benchmarks
(``benchmarks/bench_rigs.py``): a BVH clip retargeted onto a rigged body with
the floor placement animate uses (``--floor auto``), then

* ``frame0_cm``: the skinned body's lowest point at the first frame above the
  body's rest floor (its lowest rest point), cm; ``median_cm`` the median over
  the clip;
* ``travel_m``: the hips' horizontal path on the body, against
  ``clip_travel_scaled_m``, the clip's own hips path scaled by the ratio of
  the two skeletons' leg lengths (thigh + shin, both sides averaged);
  ``travel_err`` their relative difference (a clip that barely moves is
  judged against 20 cm);
* ``mapped``: the key joints paired (:func:`retarget.match_clip`), its
  ``confidence``; ``units`` the unit the reader chose.

Arrays are numpy; metres internally.
"""
from __future__ import annotations

import numpy as np

from ..io.bvh import read_bvh
from .clip_start import leading_rest_frames
from .floor import lowest_points, place_on_floor
from .retarget import match_clip, retarget
from .rig_match import find_roles

#: issue 18's limits: first frame within 3 cm of the floor, the clip's median within 5 cm, travel within 10 %
LIMITS = {"frame0_cm": 3.0, "median_cm": 5.0, "travel_err": 0.10}


def leg_length(names, parents, positions) -> float:
    """Mean over both sides of thigh + shin length, from the roles of
    :func:`rig_match.find_roles` (independent of the retargeting's pairing)."""
    r = find_roles(names, parents, positions).roles
    out = []
    for s in "lr":
        a, b, c = (r[f"{k}_{s}"] for k in ("thigh", "shin", "foot"))
        out.append(np.linalg.norm(positions[b] - positions[a]) + np.linalg.norm(positions[c] - positions[b]))
    return float(np.mean(out))


def clip_on_body(clip, char, max_eval: int = 40) -> dict:
    """Floor and travel figures of the BVH file ``clip`` retargeted onto
    ``char`` (a rigged :class:`model.Character`) at 30 fps, evaluated on at
    most ``max_eval`` frames spread over the clip (module docstring)."""
    motion = read_bvh(clip)
    # CMU conversions start with the converter's rest frame (a T-pose): skip it, as `animate` does
    start = leading_rest_frames(motion)
    sk = char.skeleton
    match = match_clip(motion, sk)
    rt = retarget(motion, sk, start=start, fps=30)
    rt, shift = place_on_floor(rt, sk, char.body, "auto")
    body = char.body
    floor = float(body.points[:, 1].min())
    frames = np.unique(np.linspace(0, rt.n_frames - 1, min(max_eval, rt.n_frames)).astype(int))
    low = lowest_points(body.points, body.joint_indices, body.joint_weights, sk.bind_world, rt.world, frames)
    sh = match.source.roles["hips"]
    th = match.target.roles["hips"]
    # horizontal path length over the evaluated frames (clips may walk in loops)
    src_frames = np.round(rt.source_frames[frames]).astype(int)
    gpos = motion.global_positions(src_frames)[:, sh][:, [0, 2]]
    clip_travel = float(np.linalg.norm(np.diff(gpos, axis=0), axis=1).sum())
    srest = motion.rest_global_transforms()[:, 3, :3]
    scale = leg_length(sk.joint_names, sk.parents, sk.bind_positions()) / leg_length(
        motion.joint_names, motion.parents, srest)
    p = rt.positions()[frames][:, th][:, [0, 2]]
    travel = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
    return {"frame0_cm": 100 * (low[0] - floor), "median_cm": 100 * float(np.median(low - floor)),
            "travel_m": travel, "clip_travel_scaled_m": clip_travel * scale,
            "travel_err": abs(travel - clip_travel * scale) / max(clip_travel * scale, 0.2),
            "mapped": match.ok, "confidence": match.confidence, "shift_cm": 100 * shift,
            "units": motion.units}


def within_limits(figures: dict) -> bool:
    """Whether :func:`clip_on_body`'s figures meet :data:`LIMITS` (and the key joints are paired)."""
    return (bool(figures["mapped"]) and abs(figures["frame0_cm"]) <= LIMITS["frame0_cm"]
            and abs(figures["median_cm"]) <= LIMITS["median_cm"] and figures["travel_err"] <= LIMITS["travel_err"])
