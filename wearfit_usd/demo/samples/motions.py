"""The project's own procedural BVH clips (authored by formula, not mocap).

Skeleton: the CMU MotionBuilder-style joint names (Hips, LeftUpLeg, LeftLeg,
LeftFoot, LeftToeBase, Spine, Spine1, Neck, Head, LeftShoulder, LeftArm,
LeftForeArm, LeftHand and Right...), rest pose a T-pose (arms along +-X),
Y up, facing +Z, character's left = +X, ZYX rotation channels, 30 fps.
Files are written in CENTIMETRES (``scale = 0.01`` m per unit; hips 95 cm
above the floor).

Clips (60 frames = 2 s each):

* ``walk``: two gait cycles of 1 s, legs alternate, arms swing opposite,
  the root advances at a constant 1.1 m/s along +Z, the lower foot on the floor;
* ``arm_raise``: both arms from down at the sides to above the head and back;
* ``squat``: knees bend to a deep squat with the arms forward and back up,
  feet flat on the floor;
* ``look``: standing, the head nods, turns and tilts, the chest twists and
  bends sideways (with the others, the example poses the skinned items are
  fitted to: :mod:`animate.skin_fit`).

Regenerate (deterministic) with ``python3 -m wearfit_usd.samples.motions``
(writes ``motions/`` at the repository root and ``wearfit_usd/motions/``).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ...io.bvh import write_bvh
from ...transforms import axis_rotation, matrix_to_euler

FPS = 30
FRAMES = 60
SCALE = 0.01  # metres per file unit (centimetres)

#: (name, parent index, rest offset from the parent in metres)
SKELETON: list[tuple[str, int, tuple[float, float, float]]] = [
    ("Hips", -1, (0.0, 0.0, 0.0)),
    ("LeftUpLeg", 0, (0.09, -0.03, 0.0)),
    ("LeftLeg", 1, (0.0, -0.42, 0.0)),
    ("LeftFoot", 2, (0.0, -0.42, 0.0)),
    ("LeftToeBase", 3, (0.0, -0.065, 0.125)),
    ("RightUpLeg", 0, (-0.09, -0.03, 0.0)),
    ("RightLeg", 5, (0.0, -0.42, 0.0)),
    ("RightFoot", 6, (0.0, -0.42, 0.0)),
    ("RightToeBase", 7, (0.0, -0.065, 0.125)),
    ("Spine", 0, (0.0, 0.08, -0.01)),
    ("Spine1", 9, (0.0, 0.2, 0.0)),
    ("Neck", 10, (0.0, 0.23, 0.0)),
    ("Head", 11, (0.0, 0.1, 0.02)),
    ("LeftShoulder", 10, (0.03, 0.19, 0.0)),
    ("LeftArm", 13, (0.14, 0.0, 0.0)),
    ("LeftForeArm", 14, (0.28, 0.0, 0.0)),
    ("LeftHand", 15, (0.25, 0.0, 0.0)),
    ("RightShoulder", 10, (-0.03, 0.19, 0.0)),
    ("RightArm", 17, (-0.14, 0.0, 0.0)),
    ("RightForeArm", 18, (-0.28, 0.0, 0.0)),
    ("RightHand", 19, (-0.25, 0.0, 0.0)),
]
NAMES = [n for n, _, _ in SKELETON]
PARENTS = np.array([p for _, p, _ in SKELETON], dtype=np.int64)
OFFSETS = np.array([o for _, _, o in SKELETON], dtype=np.float64)
HIP_HEIGHT = 0.95
ANKLE_HEIGHT = HIP_HEIGHT - 0.03 - 0.84  # 0.08 m in the rest pose
CLIPS = ["walk", "arm_raise", "squat", "look"]


def _rot(axis: str, deg) -> np.ndarray:
    """Row-vector rotation matrices (F, 3, 3) about a world axis ("x", "y"
    or "z") by ``deg`` (right-handed, column-vector sense)."""
    return axis_rotation("xyz".index(axis), np.radians(np.asarray(deg, dtype=np.float64)))


def forward_kinematics(rot: np.ndarray, root: np.ndarray) -> np.ndarray:
    """Joint world positions (F, J, 3) from local rotations (F, J, 3, 3)
    (row-vector) and root positions (F, 3)."""
    F, J = rot.shape[:2]
    wr = np.empty_like(rot)
    pos = np.empty((F, J, 3))
    for j in range(J):
        p = PARENTS[j]
        if p < 0:
            wr[:, j] = rot[:, j]
            pos[:, j] = root
        else:
            wr[:, j] = rot[:, j] @ wr[:, p]
            pos[:, j] = pos[:, p] + OFFSETS[j] @ wr[:, p]
    return pos


def _identity(F: int) -> np.ndarray:
    return np.tile(np.eye(3), (F, len(NAMES), 1, 1))


def _arms_down(rot, amount_deg, swing_deg=None):
    """Lower both arms by ``amount_deg`` from the T-pose (about Z), then swing
    them forward/back by ``swing_deg`` (about X, positive = left arm forward)."""
    la, ra = NAMES.index("LeftArm"), NAMES.index("RightArm")
    rot[:, la] = _rot("z", -amount_deg)
    rot[:, ra] = _rot("z", amount_deg)
    if swing_deg is not None:
        rot[:, la] = rot[:, la] @ _rot("x", -swing_deg)
        rot[:, ra] = rot[:, ra] @ _rot("x", swing_deg)
    return rot


def _feet_on_floor(rot, root):
    """Lift/lower the root so the lowest ankle sits at the rest ankle height."""
    pos = forward_kinematics(rot, root)
    ank = pos[:, [NAMES.index("LeftFoot"), NAMES.index("RightFoot")], 1].min(axis=1)
    root = root.copy()
    root[:, 1] += ANKLE_HEIGHT - ank
    return root


def walk(frames: int = FRAMES, period: float = 1.0, speed: float = 1.1):
    """Returns (root_positions (F, 3), rotations (F, J, 3, 3))."""
    t = np.arange(frames) / FPS
    w = 2 * np.pi * t / period
    rot = _identity(frames)
    hip_amp, knee_amp = 22.0, 45.0
    for side, ph in (("Left", 0.0), ("Right", np.pi)):
        fwd = hip_amp * np.sin(w + ph)                     # thigh forward angle
        swing = np.maximum(np.cos(w + ph), 0.0) ** 1.5      # the leg moving forward
        knee = 5.0 + knee_amp * swing
        rot[:, NAMES.index(f"{side}UpLeg")] = _rot("x", -fwd)
        rot[:, NAMES.index(f"{side}Leg")] = _rot("x", knee)
        rot[:, NAMES.index(f"{side}Foot")] = _rot("x", -0.5 * knee + 0.3 * fwd)
    rot = _arms_down(rot, 75.0, swing_deg=18.0 * np.sin(w + np.pi))  # opposite to the left leg
    for side in ("Left", "Right"):
        rot[:, NAMES.index(f"{side}ForeArm")] = _rot("y", (-1 if side == "Left" else 1) * 12.0)
    rot[:, NAMES.index("Spine")] = _rot("y", 4.0 * np.sin(w))
    root = np.stack([0.02 * np.sin(w), np.full(frames, HIP_HEIGHT), speed * t], axis=1)
    return _feet_on_floor(rot, root), rot


def arm_raise(frames: int = FRAMES):
    t = np.arange(frames) / (frames - 1)
    lift = np.sin(np.pi * t) ** 2          # 0 -> 1 -> 0
    down = 80.0 - 160.0 * lift             # 80 deg below horizontal -> 80 above
    rot = _identity(frames)
    rot = _arms_down(rot, down)
    root = np.tile([0.0, HIP_HEIGHT, 0.0], (frames, 1))
    return _feet_on_floor(rot, root), rot


def squat(frames: int = FRAMES):
    t = np.arange(frames) / (frames - 1)
    k = np.sin(np.pi * t) ** 2
    thigh = 85.0 * k
    rot = _identity(frames)
    for side in ("Left", "Right"):
        rot[:, NAMES.index(f"{side}UpLeg")] = _rot("x", -thigh)
        rot[:, NAMES.index(f"{side}Leg")] = _rot("x", 1.45 * thigh)
        rot[:, NAMES.index(f"{side}Foot")] = _rot("x", -0.45 * thigh)
    rot[:, NAMES.index("Spine")] = _rot("x", 0.35 * thigh)
    la, ra = NAMES.index("LeftArm"), NAMES.index("RightArm")
    front = 80.0 * (1 - k) + 0.0
    # arms: hanging down (80 deg) -> straight forward at the bottom of the squat
    rot[:, la] = _rot("z", -front) @ _rot("y", -90.0 * k)
    rot[:, ra] = _rot("z", front) @ _rot("y", 90.0 * k)
    root = np.tile([0.0, HIP_HEIGHT, 0.0], (frames, 1))
    # keep the ankles where they are in the rest pose (z) and on the floor (y)
    pos = forward_kinematics(rot, root)
    root[:, 2] -= pos[:, NAMES.index("LeftFoot"), 2] - OFFSETS[[1, 2, 3], 2].sum()
    return _feet_on_floor(rot, root), rot


def look(frames: int = FRAMES):
    """Standing, arms at the sides: the head nods (25 deg down and up), turns
    (40 deg each way) and tilts (12 deg), the chest twists (15 deg) and bends
    sideways (8 deg); starts and ends in the rest pose."""
    t = np.arange(frames) / (frames - 1)
    rot = _identity(frames)
    rot = _arms_down(rot, 75.0)
    nod, turn, tilt = 25.0 * np.sin(2 * np.pi * t), 40.0 * np.sin(4 * np.pi * t), 12.0 * np.sin(6 * np.pi * t)
    rot[:, NAMES.index("Neck")] = _rot("x", 0.4 * nod) @ _rot("y", 0.4 * turn) @ _rot("z", 0.4 * tilt)
    rot[:, NAMES.index("Head")] = _rot("x", 0.6 * nod) @ _rot("y", 0.6 * turn) @ _rot("z", 0.6 * tilt)
    rot[:, NAMES.index("Spine1")] = _rot("y", 15.0 * np.sin(2 * np.pi * t)) @ _rot("z", 8.0 * np.sin(4 * np.pi * t))
    root = np.tile([0.0, HIP_HEIGHT, 0.0], (frames, 1))
    return _feet_on_floor(rot, root), rot


def make_clip(name: str):
    """(root_positions (F, 3) metres, rotations (F, J, 3, 3) row-vector)."""
    return {"walk": walk, "arm_raise": arm_raise, "squat": squat, "look": look}[name]()


def write_clips(out_dirs) -> dict[str, list[Path]]:
    """Write every clip as ``<name>.bvh`` into each folder of ``out_dirs``."""
    written: dict[str, list[Path]] = {}
    for name in CLIPS:
        root, rot = make_clip(name)
        eul = matrix_to_euler(rot, "ZYX")
        eul = np.round(eul, 4) + 0.0  # stable text, no "-0.0000"
        for d in out_dirs:
            d = Path(d)
            d.mkdir(parents=True, exist_ok=True)
            path = d / f"{name}.bvh"
            write_bvh(path, NAMES, PARENTS, OFFSETS, root, eul, order="ZYX",
                      frame_time=1.0 / FPS, scale=SCALE, precision=4)
            written.setdefault(name, []).append(path)
    return written


def default_dirs() -> list[Path]:
    """The package's motions folder, plus ``motions/`` at the repository root
    when running from a checkout."""
    pkg = Path(__file__).resolve().parents[2] / "motions"
    dirs = [pkg]
    repo = pkg.parents[1]
    if (repo / "pyproject.toml").exists():
        dirs.insert(0, repo / "motions")
    return dirs


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    dirs = [Path(a) for a in argv] or default_dirs()
    for name, paths in write_clips(dirs).items():
        print(name, " ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
