"""Where a clip's motion starts: the converter's rest frame at its head.

Many BVH conversions (the CMU library's, the Daz-friendly ones) put the
skeleton's rest pose, a T-pose, in frame 0 and the captured motion from
frame 1 on. Played as it is, a shot opens in a T-pose and snaps into the
motion in one frame (at 120 fps, 60-160 degrees at some joint in 1/120 s),
and the dressing in "the clip's first frame pose" dresses the T-pose.

:func:`leading_rest_frames` finds such frames from the motion alone. With
``step(f)`` the largest joint rotation change between frames f and f+1,

    step(f) = max_j angle(R_j(f), R_j(f+1)),    angle(A, B) = arccos((tr(A^T B) - 1) / 2),

the rest frames are the leading run of steps each over ``ratio`` x the 95th
percentile of the steps after the first ``max_run`` (the clip's own pace)
and over ``min_step``, at most ``max_run`` long, together over
``min_jump``. Measured on the clips of the data set:

* the CMU conversions: one step of 79-162 degrees, then at most 18 (the
  pirouette's second step, against its pace of 27.5);
* the Daz conversion blends its rest into the motion over four frames:
  24, 25, 22 and 15 degrees, against a pace of 3.6 (before, only a single
  first step was looked for, and this clip opened in its T-pose);
* clips that start in motion (the Mixamo-named and inch-unit ones, the 3ds
  Max CMU conversion): a first step of 3-8 degrees.

Arrays are numpy; angles in degrees.
"""
from __future__ import annotations

import numpy as np

REST_MIN_JUMP = 30.0  # degrees: the whole run of rest steps, at least
REST_RATIO = 2.0      # x the clip's pace (95th percentile of its later steps)
REST_MIN_STEP = 10.0  # degrees: a smaller step is motion
REST_MAX_RUN = 8      # frames: the longest blend from a rest into the motion
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
                        window: int = REST_WINDOW, min_step: float = REST_MIN_STEP,
                        max_run: int = REST_MAX_RUN) -> int:
    """The number of leading frames of ``motion`` (a :class:`io.bvh.BVHMotion`)
    that are a converter's rest pose or its blend into the motion (module
    docstring): 0 when the clip starts in motion; the first frame of motion
    otherwise (1 for the CMU conversions). Clips of fewer than 3 frames
    start at 0."""
    n = int(motion.n_frames)
    if n < 3:
        return 0
    steps = rotation_steps(motion.local_rotations(np.arange(min(n, window + 1))))
    later = steps[max_run:] if len(steps) > max_run + 1 else steps[1:]
    pace = float(np.percentile(later, 95))
    # a run longer than max_run is fast motion, not a blend from a rest
    big = steps[:max_run + 1] > max(ratio * pace, min_step)
    if big.all():
        return 0
    run = int(np.argmin(big))
    if run == 0 or float(steps[:run].sum()) <= min_jump:
        return 0
    return run
