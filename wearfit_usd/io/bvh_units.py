"""BVH dialect decisions that need more than the header: units from the
skeleton's standing height, and what position channels on non-root joints
mean.

* **Units.** A person is 1.4-2.1 m tall. The standing height of the rest
  skeleton is measured robustly (splayed CMU legs, hanging or raised arms):
  the larger of its vertical extent and 0.9 x the bone-path length from the
  lowest joint to the highest one. Among m, dm, cm, mm, inch and CMU units
  (1/0.45 inch) the unit that puts that height in the human range, closest
  to 1.7 m, wins (outside the range: the closest, as before).
* **Position channels on non-root joints.** Some exporters (game-studio
  datasets) repeat each joint's OFFSET in its position channels every frame:
  the channels then *are* the local translation, not an addition to the
  OFFSET (added, every bone would double). When the channels of most such
  joints equal their OFFSETs in the first frame, the file is read as
  ``"absolute"`` (translation = channels); otherwise ``"add"`` (translation
  = OFFSET + channels, MakeHuman's reading, zero channels at rest).

Plain numpy, no file reading: :mod:`wearfit_usd.io.bvh` calls these.
"""
from __future__ import annotations

import math

import numpy as np

#: metres per CMU unit (ASF ``length 0.45``: 1 unit = 1/0.45 inch)
CMU_UNIT_M = 0.0254 / 0.45

#: candidate units, metres per unit
UNITS: dict[str, float] = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "inch": 0.0254,
                           "cmu": CMU_UNIT_M}

#: the range of adult standing heights accepted, metres
HUMAN_HEIGHT_M = (1.4, 2.1)


def standing_height(parents, positions, up: int = 1) -> float:
    """Standing height of a rest skeleton, in its own units.

    Parameters
    ----------
    parents : (J,) parent indices (-1 for roots), parents before children.
    positions : (P, 3) rest positions; the first J rows are the joints, any
        further rows End Sites (not on a path, only in the vertical extent).
    up : index of the up axis.

    Returns
    -------
    max(vertical extent, 0.9 x bone-path length from the lowest joint to the
    highest joint).
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    parents = np.asarray(parents, dtype=np.int64)
    n = len(parents)
    if not len(pos):
        return 0.0
    extent = float(np.ptp(pos[:, up]))
    if n < 2:
        return extent
    lo, hi = int(np.argmin(pos[:n, up])), int(np.argmax(pos[:n, up]))
    up_lo, up_hi = [], []
    j = lo
    while j >= 0:
        up_lo.append(j)
        j = parents[j]
    j = hi
    while j >= 0:
        up_hi.append(j)
        j = parents[j]
    common = set(up_lo) & set(up_hi)
    if not common:
        return extent
    path = [k for k in up_lo if k not in common] + [k for k in up_hi if k not in common]
    length = float(sum(np.linalg.norm(pos[k] - pos[parents[k]]) for k in path))
    return max(extent, 0.9 * length)


def choose_unit(height_units: float) -> tuple[float, str]:
    """(metres per unit, unit name) for a skeleton ``height_units`` tall.

    The unit putting the height in :data:`HUMAN_HEIGHT_M`, closest to 1.7 m
    (log scale); when none does, the closest overall; ``(1.0, "m
    (assumed)")`` for a zero, sub-micrometre (a flat skeleton: no unit can
    make it a person) or non-finite height.
    """
    if not height_units > 1e-6 or not math.isfinite(height_units):
        return 1.0, "m (assumed)"
    lo, hi = HUMAN_HEIGHT_M

    def dist(u):
        return abs(math.log(height_units * UNITS[u] / 1.7))

    inside = [u for u in UNITS if lo <= height_units * UNITS[u] <= hi]
    best = min(inside or list(UNITS), key=dist)
    if best == "cmu":
        return CMU_UNIT_M, "cmu (1 unit = 0.056444 m)"
    return UNITS[best], best


def position_mode(parents, offsets, channels, first_values, channel_start) -> str:
    """How to read position channels on non-root joints: "absolute" when
    they equal the OFFSETs (in the first frame) for most such joints, else
    "add".

    Parameters
    ----------
    parents : (J,) parent indices.
    offsets : (J, 3) OFFSETs, file units and axes.
    channels : per joint, its channel names.
    first_values : (C,) the first motion row (file units); None or empty: "add".
    channel_start : (J,) first column of each joint.

    Returns
    -------
    "absolute" or "add".
    """
    if first_values is None or not len(first_values):
        return "add"
    off = np.asarray(offsets, dtype=np.float64).reshape(-1, 3)
    scale = float(np.linalg.norm(off, axis=1).max()) or 1.0
    equal = total = 0
    for j, chans in enumerate(channels):
        if parents[j] < 0:
            continue
        cols = [(a, channel_start[j] + chans.index(f"{ax}position"))
                for a, ax in enumerate("XYZ") if f"{ax}position" in chans]
        if not cols:
            continue
        total += 1
        v = np.array([first_values[c] for _, c in cols])
        o = off[j, [a for a, _ in cols]]
        if np.linalg.norm(o) > 1e-6 * scale and np.linalg.norm(v - o) <= 0.02 * np.linalg.norm(o) + 1e-6 * scale:
            equal += 1
    return "absolute" if total and equal >= 0.8 * total else "add"
