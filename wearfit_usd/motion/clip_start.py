"""Where a clip's motion starts: the converter's rest frame at its head.

Many BVH conversions (the CMU library's, the Daz-friendly ones) put the
skeleton's rest pose, a T-pose, in frame 0 and the captured motion from
frame 1 on. Played as it is, a shot opens in a T-pose and snaps into the
motion in one frame (at 120 fps, 60-160 degrees at some joint in 1/120 s),
and the dressing in "the clip's first frame pose" dresses the T-pose.

:func:`leading_rest_frames` finds such a frame from the motion alone: the
largest joint rotation change between frames 0 and 1,

    jump = max_j angle(R_j(0), R_j(1)),    angle(A, B) = arccos((tr(A^T B) - 1) / 2),

is a rest frame when it is over ``min_jump`` and over ``ratio`` x the
largest such change between later consecutive frames (the first
``window``). Measured on the CMU clips of the data set: 79-162 degrees
against at most 41 in the motion after it (5-28 on all but the pirouette);
on clips that start in motion (the Mixamo-named and inch-unit ones, the
3ds Max CMU conversion) 3-8 degrees.

Arrays are numpy; angles in degrees.
"""
from __future__ import annotations

import numpy as np

REST_MIN_JUMP = 30.0  # degrees: a smaller first step is motion
REST_RATIO = 2.0      # x the largest later step
REST_WINDOW = 240     # frames looked at after the first


def rotation_steps(rotations: np.ndarray) -> np.ndarray:
    """(F - 1,) the largest joint rotation change, degrees, between
    consecutive frames of ``rotations`` (F, J, 3, 3)."""
    r = np.asarray(rotations, dtype=np.float64)
    if r.ndim != 4 or r.shape[-2:] != (3, 3):
        raise ValueError(f"rotations: expected (F, J, 3, 3), got {r.shape}")
    if len(r) < 2:
        return np.zeros(0)
    cos = (np.einsum("fjab,fjab->fj", r[:-1], r[1:]) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max(axis=1)


def leading_rest_frames(motion, min_jump: float = REST_MIN_JUMP, ratio: float = REST_RATIO,
                        window: int = REST_WINDOW) -> int:
    """1 when frame 0 of ``motion`` (a :class:`io.bvh.BVHMotion`) is a
    converter's rest frame (module docstring), else 0. Clips of fewer than
    3 frames start at 0."""
    n = int(motion.n_frames)
    if n < 3:
        return 0
    steps = rotation_steps(motion.local_rotations(np.arange(min(n, window + 1))))
    jump, later = float(steps[0]), float(steps[1:].max())
    return int(jump > min_jump and jump > ratio * later)
