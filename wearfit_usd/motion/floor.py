"""Feet on the floor: a retargeted clip moved up or down so the body's lowest
point at the first frame sits on the body's rest floor.

The shift is one constant vertical offset for every frame and joint, so the
clip's own vertical motion (jumps, bobbing) is kept and retargeting adds
none. A capture floor that is not level (CMU's walks rise 5-13 cm over 3-4
m: about 1 degree) is levelled first: each frame moves vertically by the
fitted slope times the root's horizontal travel, a rigid per-frame
translation that leaves clips staying in place untouched.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .skinning import Skinner, skinning_matrices

#: ``--floor`` choices: "auto" (first frame on the rest floor) or "keep"
FLOOR_MODES = ("auto", "keep")

#: how far (m) frame 0 may stay off the floor to stand the whole clip better
FRAME0_SLACK_M = 0.025

#: steepest capture-floor tilt levelled (degrees); steeper is a real slope
MAX_TILT_DEG = 3.0


def lowest_points(body_points, joint_indices, joint_weights, bind_world, world, frames=None) -> np.ndarray:
    """Height (internal Y, metres) of the body's lowest point per frame.

    Parameters
    ----------
    body_points : (N, 3) bind-pose body points.
    joint_indices, joint_weights : (N, K) skin influences.
    bind_world : (J, 4, 4) bind transforms.
    world : (F, J, 4, 4) posed joint transforms.
    frames : frame indices to evaluate (None: all).

    Returns
    -------
    (F',) lowest Y per evaluated frame.
    """
    world = np.asarray(world)
    sel = np.arange(world.shape[0]) if frames is None else np.asarray(frames, dtype=int)
    mats = skinning_matrices(bind_world, world[sel])
    if len(mats) == 0:
        return np.zeros(0)
    # one skinning matrix for every frame; only the heights (column Y) are needed
    sk = Skinner(body_points, joint_indices, joint_weights, mats.shape[-3])
    return (sk.matrix @ mats[:, :, :, 1].reshape(len(mats), -1).T).min(axis=0)


def floor_shift(body, skeleton, world, slack: float = FRAME0_SLACK_M, samples: int = 60) -> float:
    """Vertical shift (metres) putting the body's lowest point at frame 0 on
    its rest floor (the lowest bind-pose point).

    Mocap floors are rarely level (a clip's lowest point may rise by 10 cm
    over a walk): within ``slack`` of the frame-0 shift, the shift that puts
    the clip's median lowest point (over ``samples`` frames) on the floor is
    taken, so frame 0 stays within ``slack`` of the floor and the clip as a
    whole stands on it as well as its own floor allows.

    Parameters
    ----------
    body : :class:`~wearfit_usd.model.Mesh`, skinned to ``skeleton``.
    skeleton : :class:`~wearfit_usd.model.Skeleton`.
    world : (F, J, 4, 4) posed joint transforms.
    slack : metres frame 0 may stay off the floor (0: exactly on it).
    samples : frames evaluated for the median.
    """
    n = np.asarray(world).shape[0]
    frames = np.unique(np.linspace(0, n - 1, min(samples, n)).astype(int))
    low = lowest_points(body.points, body.joint_indices, body.joint_weights,
                        skeleton.bind_world, world, frames)
    floor = float(body.points[:, 1].min())
    dy0 = floor - float(low[0])
    dym = floor - float(np.median(low))
    return dy0 + float(np.clip(dym - dy0, -slack, slack))


def floor_tilt(ground: np.ndarray, lows: np.ndarray, max_deg: float = MAX_TILT_DEG,
               min_travel: float = 0.5) -> np.ndarray:
    """Slope (2,) of a tilted capture floor: d(lowest point)/d(horizontal
    position), fitted to the frames in contact (the lower half of the
    residuals, twice). Zero when the clip travels less than ``min_travel``
    metres or the tilt exceeds ``max_deg`` (a real slope or stairs).

    Parameters
    ----------
    ground : (F, 2) horizontal (X, Z) position of the root per frame.
    lows : (F,) lowest body point per frame.
    """
    g = np.asarray(ground, dtype=np.float64)
    y = np.asarray(lows, dtype=np.float64)
    if len(g) < 4:
        return np.zeros(2)
    # along the directions the clip travels far enough to measure a slope
    _, sv, vt = np.linalg.svd(g - g.mean(0), full_matrices=False)
    extent = 4.0 * sv / np.sqrt(len(g))  # about the peak-to-peak travel
    axes = vt[extent >= min_travel]
    if not len(axes):
        return np.zeros(2)
    a = np.column_stack([np.ones(len(g)), (g - g[0]) @ axes.T])
    keep = np.ones(len(g), dtype=bool)
    coef = np.zeros(3)
    for _ in range(3):
        coef = np.linalg.lstsq(a[keep], y[keep], rcond=None)[0]
        res = y - a @ coef
        keep = res <= np.median(res[keep])
        if keep.sum() < 4:
            break
    slope = coef[1:] @ axes
    if np.degrees(np.arctan(np.linalg.norm(slope))) > max_deg:
        return np.zeros(2)
    return slope


def place_on_floor(rt, skeleton, body, mode: str = "auto", samples: int = 60):
    """A :class:`~wearfit_usd.motion.retarget.Retargeted` (or a
    :class:`~wearfit_usd.motion.retarget.RetargetStream`, corrected as its
    frames are computed) standing on the body's rest floor
    (``mode="auto"``) or unchanged (``"keep"``).

    auto: a tilted capture floor is levelled (each frame moved vertically by
    the fitted slope times the root's horizontal travel since frame 0, see
    :func:`floor_tilt`; a rigid per-frame translation, zero for clips that
    stay in place), then one constant shift puts frame 0 on the floor
    (:func:`floor_shift`). Horizontal motion is untouched.

    Returns
    -------
    (Retargeted, constant shift in metres); the report gains
    ``floor_shift_m`` and ``floor_tilt_deg``.
    """
    if mode not in FLOOR_MODES:
        raise ValueError(f"floor mode must be one of {FLOOR_MODES}, got {mode!r}")
    n = rt.n_frames if hasattr(rt, "blocks") else np.asarray(rt.world).shape[0]
    if mode == "keep" or body is None or not body.is_skinned or n == 0:
        return rt, 0.0
    frames = np.unique(np.linspace(0, n - 1, min(samples, n)).astype(int))
    root = int(np.flatnonzero(np.asarray(skeleton.parents) < 0)[0])
    carrier = rt.report.get("root_joint")
    if carrier in skeleton.joint_names:
        root = skeleton.joint_names.index(carrier)
    if hasattr(rt, "blocks"):
        # a RetargetStream: the sampled frames only; the correction is applied
        # as its frames are computed (floor_dy, floor_slope)
        sampled = np.stack([rt.world(f, f + 1)[0] for f in frames])
    else:
        sampled = np.asarray(rt.world)[frames]
    ground = sampled[:, root, 3][:, [0, 2]]
    lows = lowest_points(body.points, body.joint_indices, body.joint_weights, skeleton.bind_world, sampled)
    slope = floor_tilt(ground, lows)
    ground0 = ground[0].copy()  # frames[0] == 0
    if slope.any():
        sampled = sampled.copy()
        sampled[:, :, 3, 1] -= ((ground - ground0) @ slope)[:, None]
    dy = floor_shift(body, skeleton, sampled, samples=len(frames))
    if hasattr(rt, "blocks"):
        return replace(rt, floor_dy=float(dy), floor_slope=slope if slope.any() else None,
                       floor_ground0=ground0), dy
    world = np.asarray(rt.world).copy()
    if slope.any():
        world[:, :, 3, 1] -= ((world[:, root, 3][:, [0, 2]] - ground0) @ slope)[:, None]
    world[:, :, 3, 1] += dy
    report = dict(rt.report)
    report["floor_shift_m"] = dy
    report["floor_tilt_deg"] = float(np.degrees(np.arctan(np.linalg.norm(slope))))
    return replace(rt, world=world, local=skeleton.local_from_world(world), report=report), dy
