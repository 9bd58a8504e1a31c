"""BVH motion capture: reader, forward kinematics and writer.

Reading (:func:`read_bvh`) returns a :class:`BVHMotion` in internal space:
metres, Y up, character facing +Z (left = +X), row-vector 4x4 matrices like
USD's Gf (``p' = [p, 1] @ M``; ``world[j] = local[j] @ world[parent[j]]``).

BVH semantics used here:

* The rotation channels of a joint, listed left to right (for example
  ``Zrotation Xrotation Yrotation``), are intrinsic rotations: the
  column-vector matrix is ``Rz @ Rx @ Ry``. In the row-vector convention this
  is ``ry @ rx @ rz`` with ``r = R.T``.
* A joint's local translation is ``OFFSET + (Xposition, Yposition,
  Zposition)`` when it has position channels, for the root too (additive,
  like three.js's loader). This is what the MakeHuman exporter means: its
  non-root position channels are zero in the rest pose, and with its root
  (OFFSET z 0.63 dm) the feet of its run pose land on MakeHuman's ground
  plane (2 cm above, instead of 4 cm below when the channels replace the
  OFFSET). CMU and Daz files have a zero root OFFSET, so either reading
  agrees there; :func:`write_bvh` writes a zero root OFFSET.
* Units: ``scale`` metres per file unit, detected from the dialect (CMU units
  = 0.056444 m) or from the skeleton height (m, dm, cm, mm, inches) unless
  given.
* Up axis: Z-up files (MakeHuman/Blender exports, -Y forward) are rotated to
  internal Y-up, +Z forward: file (x, y, z) -> internal (x, z, -y).

Writing (:func:`write_bvh`) produces a standard dialect: root with 6 channels,
other joints with 3 rotation channels, ``End Site`` for leaves, Y up.
"""
from __future__ import annotations

import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import BVHError
from ..transforms import Z_UP_TO_Y_UP, euler_to_matrix
from .atomic import atomic_output
from .bvh_units import choose_unit, position_mode, standing_height

#: metres per CMU unit (ASF ``length 0.45``: 1 unit = 1/0.45 inch)
CMU_UNIT_M = 0.0254 / 0.45

_UNITS = {  # name -> metres per unit, for the height heuristic
    "m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "inch": 0.0254,
}
_AXES = "XYZ"
_ROT_CHANNELS = {"Xrotation": 0, "Yrotation": 1, "Zrotation": 2}
_POS_CHANNELS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}
#: input bounds: a clip past them is refused with the file line (values beyond
#: them only overflow or lose all precision in the kinematics)
MAX_JOINTS = 10_000
MAX_LENGTH_M = 1e4          # |offset| and |position channel| in metres
MAX_ANGLE_DEG = 1e6         # |rotation channel| in degrees
FRAME_TIME_RANGE = (1e-6, 1e6)  # seconds


# --------------------------------------------------------------------------
# data

@dataclass
class BVHMotion:
    """A parsed BVH clip in internal space (metres, Y up, facing +Z).

    joint_names: J names in file (depth-first) order.
    parents: (J,) int, -1 for a root, ``parents[j] < j``.
    offsets: (J, 3) rest offsets from the parent, metres, internal axes.
    end_sites: list of (joint index, (3,) offset in metres, internal axes).
    channels: per joint, the channel names as written.
    rotation_orders: per joint, the rotation channel letters in file order
        ("ZYX", "ZXY", ... or "" without rotation channels).
    values: (F, C) the raw motion values, file units and degrees.
    scale: metres per file unit. up_axis: "Y" or "Z" (of the file).
    """
    path: str
    joint_names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: list
    channels: list[list[str]]
    rotation_orders: list[str]
    frame_time: float
    n_frames: int
    values: np.ndarray
    scale: float
    units: str
    up_axis: str
    dialect: str
    channel_start: np.ndarray = field(default=None)  # (J,) first column of each joint
    #: non-root position channels: "add" (OFFSET + channels) or "absolute"
    #: (the channels repeat the OFFSET: they are the translation), see
    #: :func:`wearfit_usd.io.bvh_units.position_mode`
    position_mode: str = "add"
    _file_to_internal: np.ndarray = field(default=None, repr=False)  # (3, 3)

    @property
    def fps(self) -> float:
        """1 / frame_time, snapped to the nearest integer rate when the file
        rounded it (``.0083333`` -> 120, ``0.041667`` -> 24)."""
        f = 1.0 / self.frame_time
        r = round(f)
        return float(r) if r > 0 and abs(f - r) < 2e-4 * f else f

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def duration_s(self) -> float:
        return self.n_frames * self.frame_time

    def index(self, name: str) -> int:
        return self.joint_names.index(name)

    # -- kinematics -------------------------------------------------------
    def _frames(self, frames):
        if frames is None:
            return self.values
        return self.values[np.atleast_1d(np.asarray(frames))]

    def local_rotations(self, frames=None) -> np.ndarray:
        """(F, J, 3, 3) local joint rotations, row-vector, internal axes."""
        vals = self._frames(frames)
        n = vals.shape[0]
        rot = np.empty((n, self.n_joints, 3, 3))
        c = self._file_to_internal
        groups: dict[str, list[int]] = {}
        for j, order in enumerate(self.rotation_orders):
            groups.setdefault(order, []).append(j)
        for order, joints in groups.items():
            if not order:
                rot[:, joints] = np.eye(3)
                continue
            cols = np.array([[self.channel_start[j] + self.channels[j].index(f"{a}rotation")
                              for a in order] for j in joints])  # (Jg, k)
            r = euler_to_matrix(vals[:, cols], order)  # (F, Jg, 3, 3)
            rot[:, joints] = c.T @ r @ c
        return rot

    def local_translations(self, frames=None) -> np.ndarray:
        """(F, J, 3) local joint translations in metres, internal axes."""
        vals = self._frames(frames)
        n = vals.shape[0]
        t = np.broadcast_to(self.offsets, (n, self.n_joints, 3)).copy()
        for j, chans in enumerate(self.channels):
            idx = [self.channel_start[j] + chans.index(f"{a}position") if f"{a}position" in chans
                   else -1 for a in _AXES]
            if max(idx) < 0:
                continue
            p = np.zeros((n, 3))
            for a, col in enumerate(idx):
                if col >= 0:
                    p[:, a] = vals[:, col]
            if self.position_mode == "absolute" and self.parents[j] >= 0:
                p = p - np.where(np.array(idx) >= 0, self.offsets[j] @ self._file_to_internal.T
                                 / self.scale, 0.0)  # the channels replace the OFFSET
            t[:, j] += (p * self.scale) @ self._file_to_internal
        return t

    def _fk(self, rot, trans):
        n = rot.shape[0]
        grot = np.empty_like(rot)
        gpos = np.empty((n, self.n_joints, 3))
        for j, p in enumerate(self.parents):
            if p < 0:
                grot[:, j] = rot[:, j]
                gpos[:, j] = trans[:, j]
            else:
                grot[:, j] = rot[:, j] @ grot[:, p]
                gpos[:, j] = np.einsum("fi,fij->fj", trans[:, j], grot[:, p]) + gpos[:, p]
        return grot, gpos

    @staticmethod
    def _compose(rot, pos):
        m = np.zeros(rot.shape[:-2] + (4, 4))
        m[..., :3, :3] = rot
        m[..., 3, :3] = pos
        m[..., 3, 3] = 1.0
        return m

    def local_transforms(self, frames=None) -> np.ndarray:
        """(F, J, 4, 4) local joint transforms (metres, internal axes,
        row-vector): ``world[j] = local[j] @ world[parent[j]]``."""
        return self._compose(self.local_rotations(frames), self.local_translations(frames))

    def global_rotations_positions(self, frames=None):
        """(F, J, 3, 3) world rotations and (F, J, 3) world positions (m)."""
        return self._fk(self.local_rotations(frames), self.local_translations(frames))

    def global_transforms(self, frames=None) -> np.ndarray:
        """(F, J, 4, 4) world joint transforms (metres, Y up, row-vector)."""
        return self._compose(*self.global_rotations_positions(frames))

    def global_positions(self, frames=None) -> np.ndarray:
        """(F, J, 3) world joint positions in metres (Y up)."""
        return self.global_rotations_positions(frames)[1]

    def end_site_positions(self, frames=None) -> np.ndarray:
        """(F, E, 3) world positions of the End Sites, metres."""
        grot, gpos = self.global_rotations_positions(frames)
        if not self.end_sites:
            return np.zeros((grot.shape[0], 0, 3))
        par = np.array([e[0] for e in self.end_sites])
        off = np.array([e[1] for e in self.end_sites])
        return np.einsum("ei,feij->fej", off, grot[:, par]) + gpos[:, par]

    def rest_global_transforms(self) -> np.ndarray:
        """(J, 4, 4) world transforms with every rotation zero and the root at
        its OFFSET (the skeleton as written in the HIERARCHY)."""
        pos = np.zeros((self.n_joints, 3))
        for j, p in enumerate(self.parents):
            pos[j] = self.offsets[j] + (pos[p] if p >= 0 else 0.0)
        return self._compose(np.broadcast_to(np.eye(3), (self.n_joints, 3, 3)), pos)

    def rest_end_site_positions(self) -> np.ndarray:
        """(E, 3) End Site positions in the rest pose, metres."""
        rest = self.rest_global_transforms()[:, 3, :3]
        return np.array([rest[j] + off for j, off in self.end_sites]).reshape(-1, 3)

    def height_m(self) -> float:
        """Estimated standing height (m): vertical extent of the rest pose
        (joints and End Sites)."""
        pts = np.concatenate([self.rest_global_transforms()[:, 3, :3],
                              self.rest_end_site_positions()])
        return float(np.ptp(pts[:, 1]))

    def summary(self) -> dict:
        hist: dict[str, int] = {}
        for o in self.rotation_orders:
            if o:
                hist[o] = hist.get(o, 0) + 1
        return {
            "file": self.path,
            "kind": "bvh",
            "joints": self.n_joints,
            "joint_names": list(self.joint_names),
            "end_sites": len(self.end_sites),
            "frames": self.n_frames,
            "fps": round(self.fps, 4),
            "frame_time": self.frame_time,
            "duration_s": round(self.duration_s, 4),
            "channels": int(self.values.shape[1]),
            "rotation_orders": hist,
            "scale_m_per_unit": self.scale,
            "units": self.units,
            "up_axis": self.up_axis,
            "dialect": self.dialect,
            "height_m": round(self.height_m(), 3),
        }


# --------------------------------------------------------------------------
# reading

def _guess_dialect(names: list[str]) -> str:
    s = set(names)
    low = {n.lower() for n in names}
    if any(n.lower().startswith("mixamorig") for n in names):
        return "mixamo"
    if {"Hips", "LHipJoint", "LeftUpLeg", "LowerBack"} <= s:
        return "cmu_motionbuilder"
    if {"LHipJoint", "LeftHip", "LeftKnee"} <= s or {"lhipjoint", "lowerback", "chest2"} <= low:
        return "cmu_3dsmax"
    if {"hip", "abdomen", "chest"} <= low and ("lthigh" in low or "rthigh" in low):
        return "daz"
    if "root" in low and ("upperleg01.l" in low or "pelvis.l" in low):
        return "makehuman_default"
    return "generic"


class _Tokens:
    """Whitespace tokens of the HIERARCHY part, with 1-based line numbers."""

    def __init__(self, path, lines, start, stop):
        self.path = path
        self.toks: list[tuple[str, int]] = []
        for ln in range(start, stop):
            for t in lines[ln].split():
                # split '{' / '}' glued to names ("JOINT a{")
                for part in re.split(r"([{}])", t):
                    if part:
                        self.toks.append((part, ln + 1))
        self.i = 0
        self.last_line = stop

    def peek(self):
        return self.toks[self.i] if self.i < len(self.toks) else (None, self.last_line)

    def next(self, what: str):
        if self.i >= len(self.toks):
            raise BVHError(self.path, f"unexpected end of HIERARCHY (expected {what}; "
                                      "unbalanced braces?)", line=self.last_line)
        t = self.toks[self.i]
        self.i += 1
        return t

    def expect(self, word: str):
        tok, ln = self.next(repr(word))
        if tok != word:
            if word == "}" or tok == "}":
                raise BVHError(self.path, f"expected {word!r} but found {tok!r} "
                                          "(unbalanced braces?)", line=ln)
            raise BVHError(self.path, f"expected {word!r} but found {tok!r}", line=ln)
        return ln

    def number(self, what: str) -> float:
        tok, ln = self.next(what)
        try:
            v = float(tok)
        except ValueError:
            raise BVHError(self.path, f"non-numeric {what} {tok!r}", line=ln) from None
        if not math.isfinite(v):
            raise BVHError(self.path, f"non-finite {what} {tok!r}", line=ln)
        return v


def _parse_hierarchy(path, tk: _Tokens):
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[list[str]] = []
    orders: list[str] = []
    end_sites: list[tuple[int, np.ndarray]] = []

    def joint_header(parent: int) -> int:
        """Name, '{', OFFSET and CHANNELS of a ROOT/JOINT; returns its index."""
        tok, ln = tk.next("joint name")
        if tok in ("{", "}"):
            raise BVHError(path, "joint without a name", line=ln)
        name_parts = [tok]
        while tk.peek()[0] not in (None, "{") and tk.peek()[1] == ln:
            name_parts.append(tk.next("name")[0])
        name = " ".join(name_parts)
        if name in seen:
            raise BVHError(path, f"duplicate joint name {name!r}", line=ln)
        if len(names) >= MAX_JOINTS:
            raise BVHError(path, f"more than {MAX_JOINTS} joints", line=ln)
        tk.expect("{")
        j = len(names)
        names.append(name)
        seen.add(name)
        parents.append(parent)
        offset_lines.append(tk.expect("OFFSET"))
        offsets.append([tk.number("OFFSET value") for _ in range(3)])
        chans: list[str] = []
        tok, ln = tk.peek()
        if tok == "CHANNELS":
            tk.next("CHANNELS")
            ntok, nln = tk.next("channel count")
            try:
                n = int(ntok)
            except ValueError:
                raise BVHError(path, f"joint {name}: channel count {ntok!r} is not an integer",
                               line=nln) from None
            # the channel names are the rest of that line
            while tk.peek()[0] is not None and tk.peek()[1] == nln and tk.peek()[0] not in "{}":
                chans.append(tk.next("channel")[0])
            if len(chans) != n:
                raise BVHError(path, f"joint {name}: CHANNELS says {n} but lists {len(chans)} "
                                     f"channel names ({' '.join(chans)})", line=nln)
            for c in chans:
                if c not in _ROT_CHANNELS and c not in _POS_CHANNELS:
                    raise BVHError(path, f"joint {name}: unknown channel {c!r} (expected "
                                         "X/Y/Z position or rotation)", line=nln)
            rot = "".join(c[0] for c in chans if c in _ROT_CHANNELS)
            pos = [c for c in chans if c in _POS_CHANNELS]
            if len(set(rot)) != len(rot) or len(set(pos)) != len(pos):
                raise BVHError(path, f"joint {name}: unknown rotation order / repeated channel in "
                                     f"{' '.join(chans)}", line=nln)
            orders.append(rot)
        else:
            orders.append("")
        channels.append(chans)
        return j

    def parse_joint(root_line: int) -> None:
        """A ROOT and its whole subtree, with an explicit stack (no recursion
        per level: any depth parses)."""
        stack = [joint_header(-1)]
        while stack:
            j = stack[-1]
            tok, ln = tk.next("JOINT, End Site or '}'")
            if tok == "}":
                stack.pop()
            elif tok == "JOINT":
                stack.append(joint_header(j))
            elif tok == "End":
                site, sln = tk.next("Site")
                if site.lower() != "site":
                    raise BVHError(path, f"expected 'End Site', found 'End {site}'", line=sln)
                tk.expect("{")
                end_lines.append(tk.expect("OFFSET"))
                off = np.array([tk.number("End Site OFFSET value") for _ in range(3)])
                tk.expect("}")
                end_sites.append((j, off))
            elif tok == "ROOT" or tok == "MOTION":
                raise BVHError(path, f"found {tok} inside joint {names[j]} (unbalanced braces: "
                                     "missing '}')", line=ln)
            else:
                raise BVHError(path, f"joint {names[j]}: unexpected {tok!r} (expected JOINT, "
                                     "End Site or '}')", line=ln)

    seen: set[str] = set()
    offset_lines: list[int] = []
    end_lines: list[int] = []
    tok, ln = tk.next("HIERARCHY")
    if tok != "HIERARCHY":
        raise BVHError(path, f"not a BVH file: expected HIERARCHY, found {tok!r}", line=ln)
    while True:
        tok, ln = tk.peek()
        if tok is None:
            break
        tk.next("ROOT")
        if tok == "ROOT":
            parse_joint(ln)
        elif tok == "}":
            raise BVHError(path, "unbalanced braces: '}' without an open joint", line=ln)
        else:
            raise BVHError(path, f"expected ROOT, found {tok!r}", line=ln)
    if not names:
        raise BVHError(path, "HIERARCHY holds no ROOT joint", line=tk.last_line)
    return names, parents, offsets, channels, orders, end_sites, offset_lines, end_lines


def _detect_up(names, parents, offsets_file) -> str:
    """'Y' or 'Z': the axis along which the head sits above the root."""
    pos = np.zeros((len(names), 3))
    for j, p in enumerate(parents):
        pos[j] = offsets_file[j] + (pos[p] if p >= 0 else 0.0)
    low = [n.lower() for n in names]
    cand = [j for j, n in enumerate(low) if n in ("head", "mixamorig:head") or n.endswith(":head")]
    if not cand:
        cand = [j for j, n in enumerate(low) if "head" in n and "end" not in n]
    if cand:
        d = pos[cand[0]] - pos[0]
    else:  # fall back: the joint furthest from the root along Y or Z
        d = pos[np.argmax(np.abs(pos[:, 1:]).max(axis=1))] - pos[0]
    return "Z" if abs(d[2]) > abs(d[1]) and d[2] > 0 else "Y"


def _detect_scale(height_units: float, dialect: str) -> tuple[float, str]:
    if dialect.startswith("cmu"):
        return CMU_UNIT_M, "cmu (1 unit = 0.056444 m)"
    if not 1e-9 < height_units < 1e12:  # flat (or absurd) rest skeleton: no unit fits
        return 1.0, "m (assumed)"
    best = min(_UNITS, key=lambda u: abs(math.log(height_units * _UNITS[u] / 1.7)))
    return _UNITS[best], best


def _check_ranges(path, names, channels, off_file, rest_pos, end_sites, scale, values, row_lines,
                  offset_lines, end_lines) -> None:
    """Refuse offsets, rest positions and position channels beyond
    :data:`MAX_LENGTH_M` metres and rotations beyond :data:`MAX_ANGLE_DEG`
    degrees, naming the joint and the line (frame for motion values)."""
    big = ~(np.abs(off_file).max(axis=1) * scale <= MAX_LENGTH_M)
    big |= ~(np.abs(rest_pos).max(axis=1) * scale <= MAX_LENGTH_M)
    if big.any():
        j = int(np.argmax(big))
        raise BVHError(path, f"joint {names[j]}: OFFSET places it more than {MAX_LENGTH_M:g} m "
                             "from the root (extreme value)", line=offset_lines[j])
    for k, (j, o) in enumerate(end_sites):
        if not np.abs(o).max() * scale <= MAX_LENGTH_M:
            raise BVHError(path, f"joint {names[j]}: End Site OFFSET beyond {MAX_LENGTH_M:g} m "
                                 "(extreme value)", line=end_lines[k])
    if values.size == 0:
        return
    col_joint = np.repeat(np.arange(len(channels)), [len(c) for c in channels])
    is_rot = np.array([c in _ROT_CHANNELS for ch in channels for c in ch], dtype=bool)
    limit = np.where(is_rot, MAX_ANGLE_DEG, MAX_LENGTH_M / scale)
    over = np.abs(values) > limit
    if over.any():
        f, c = (int(v) for v in np.argwhere(over)[0])
        j = int(col_joint[c])
        chan = channels[j][c - int(np.flatnonzero(col_joint == j)[0])]
        unit = f"{MAX_ANGLE_DEG:g} degrees" if is_rot[c] else f"{MAX_LENGTH_M:g} m"
        raise BVHError(path, f"frame {f}, joint {names[j]}: {chan} value {values[f, c]:g} is beyond "
                             f"{unit} (extreme value)", line=row_lines[f])


def read_bvh(path, scale: float | None = None) -> BVHMotion:
    """Read a BVH file into a :class:`BVHMotion` (internal space).

    scale: metres per file unit; None = detect (CMU dialects: 0.056444 m,
    otherwise the unit among m/dm/cm/mm/inch that makes the rest skeleton
    closest to 1.7 m tall). Raises :class:`BVHError` with a line number for
    malformed files.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise BVHError(path, "file not found") from None
    except OSError as exc:
        raise BVHError(path, f"cannot read: {exc}") from None
    text = raw.decode("utf-8", errors="replace")
    lines = text.splitlines()
    motion_line = None
    for i, ln in enumerate(lines):
        if ln.strip().upper() == "MOTION" or ln.strip().upper().startswith("MOTION "):
            motion_line = i
            break
    has_hier = any(ln.strip() == "HIERARCHY" for ln in lines[:5]) or (
        lines and lines[0].lstrip("\ufeff").strip() == "HIERARCHY")
    if not has_hier:
        first = next((i for i, ln in enumerate(lines) if ln.strip()), 0)
        raise BVHError(path, "missing HIERARCHY (not a BVH file?)", line=first + 1)
    if motion_line is None:
        raise BVHError(path, "missing MOTION section (file truncated?)", line=len(lines))
    if lines[0].startswith("\ufeff"):
        lines[0] = lines[0][1:]
    tk = _Tokens(path, lines, 0, motion_line)
    names, parents, offsets, channels, orders, end_sites, offset_lines, end_lines = \
        _parse_hierarchy(path, tk)

    # ---- MOTION header
    def header(idx, key):
        while idx < len(lines) and not lines[idx].strip():
            idx += 1
        if idx >= len(lines):
            raise BVHError(path, f"missing '{key}' line after MOTION (file truncated)",
                           line=len(lines))
        m = re.match(rf"\s*{key}\s*:?\s*(\S+)\s*$", lines[idx], re.IGNORECASE)
        if not m:
            raise BVHError(path, f"expected '{key}: <value>', found {lines[idx].strip()!r}",
                           line=idx + 1)
        return idx, m.group(1)

    fl, fv = header(motion_line + 1, "Frames")
    try:
        n_frames = int(fv)
    except ValueError:
        raise BVHError(path, f"frame count {fv!r} is not an integer", line=fl + 1) from None
    if n_frames < 0:
        raise BVHError(path, f"negative frame count {n_frames}", line=fl + 1)
    tl, tv = header(fl + 1, "Frame Time")
    try:
        frame_time = float(tv)
    except ValueError:
        raise BVHError(path, f"frame time {tv!r} is not a number", line=tl + 1) from None
    if not (frame_time > 0 and math.isfinite(frame_time)):
        raise BVHError(path, f"frame time must be > 0, got {tv}", line=tl + 1)
    lo, hi = FRAME_TIME_RANGE
    if not lo <= frame_time <= hi:
        raise BVHError(path, f"frame time {tv} s is outside [{lo:g}, {hi:g}] s", line=tl + 1)

    # ---- motion rows
    n_ch = sum(len(c) for c in channels)
    rows = []
    row_lines = []
    for i in range(tl + 1, len(lines)):
        parts = lines[i].split()
        if not parts:
            continue
        if len(rows) == n_frames:
            raise BVHError(path, f"more motion rows than 'Frames: {n_frames}'", line=i + 1)
        if len(parts) != n_ch:
            raise BVHError(path, f"frame {len(rows)} has {len(parts)} values, expected {n_ch} "
                                 f"(the channel count of the HIERARCHY)"
                           + ("; file truncated?" if len(parts) < n_ch else ""), line=i + 1)
        rows.append(parts)
        row_lines.append(i + 1)
    if len(rows) < n_frames:
        raise BVHError(path, f"truncated: 'Frames: {n_frames}' but only {len(rows)} motion rows",
                       line=len(lines))
    try:
        values = np.array(rows, dtype=np.float64).reshape(n_frames, n_ch)
    except ValueError:
        for r, ln in zip(rows, row_lines):
            for tok in r:
                try:
                    float(tok)
                except ValueError:
                    raise BVHError(path, f"non-numeric value {tok!r} in frame "
                                         f"{row_lines.index(ln)}", line=ln) from None
        raise
    if not np.isfinite(values).all():
        bad = int(np.argwhere(~np.isfinite(values))[0, 0])
        raise BVHError(path, f"non-finite value (nan/inf) in frame {bad}", line=row_lines[bad])

    # ---- units, axes
    off_file = np.array(offsets, dtype=np.float64).reshape(-1, 3)
    with np.errstate(over="ignore", invalid="ignore"):  # extreme offsets: refused below
        dialect = _guess_dialect(names)
        up = _detect_up(names, parents, off_file)
        c3 = Z_UP_TO_Y_UP[:3, :3].copy() if up == "Z" else np.eye(3)
        pos = np.zeros_like(off_file)
        for j, p in enumerate(parents):
            pos[j] = off_file[j] + (pos[p] if p >= 0 else 0.0)
        ends_file = np.array([pos[j] + o for j, o in end_sites]).reshape(-1, 3)
        allp = np.concatenate([pos, ends_file]) @ c3
        height_units = float(np.ptp(allp[:, 1])) if len(allp) else 0.0
    if scale is None and not dialect.startswith("cmu"):
        with np.errstate(over="ignore", invalid="ignore"):  # extreme offsets: refused below
            scale, units = choose_unit(standing_height(parents, allp))
    elif scale is None:
        scale, units = _detect_scale(height_units, dialect)
    else:
        scale = float(scale)
        if not (scale > 0 and math.isfinite(scale)):
            raise BVHError(path, f"scale must be > 0 metres per unit, got {scale}")
        units = f"{scale:g} m/unit (given)"
    _check_ranges(path, names, channels, off_file, pos, end_sites, scale, values, row_lines,
                  offset_lines, end_lines)
    starts = np.concatenate([[0], np.cumsum([len(c) for c in channels])[:-1]]).astype(np.int64)
    return BVHMotion(
        path=str(path), joint_names=names, parents=np.array(parents, dtype=np.int64),
        offsets=(off_file * scale) @ c3,
        end_sites=[(j, (o * scale) @ c3) for j, o in end_sites],
        channels=channels, rotation_orders=orders, frame_time=frame_time, n_frames=n_frames,
        values=values, scale=scale, units=units, up_axis=up, dialect=dialect,
        channel_start=starts, _file_to_internal=c3,
        position_mode=position_mode(parents, off_file, channels, values[0] if n_frames else None,
                                    starts))


# --------------------------------------------------------------------------
# writing

def write_bvh(path, joint_names, parents, offsets, root_positions, rotations_deg,
              order: str = "ZYX", frame_time: float = 1.0 / 30.0, scale: float = 1.0,
              precision: int = 6) -> None:
    """Write a standard BVH file (Y up), atomically (temp file + rename).

    joint_names: J names; parents: (J,) int, -1 for the (single) root,
        ``parents[j] < j``. Joints are written depth-first (children in index
        order); motion columns follow that order.
    offsets: (J, 3) rest offsets from the parent joint in metres (Y up); the
        root's offset is not written (the root's position channels carry it).
    root_positions: (F, 3) root position per frame, metres.
    rotations_deg: (F, J, 3) local Euler angles in degrees, column k is the
        rotation about axis ``order[k]`` (the channel order in the file, BVH
        intrinsic semantics, see :func:`~wearfit_usd.transforms.euler_to_matrix`;
        use :func:`~wearfit_usd.transforms.matrix_to_euler` to get them from
        rotation matrices).
    order: rotation channel order for every joint, a permutation of "XYZ".
    scale: metres per file unit (e.g. 0.01 writes centimetres).
    Root: ``Xposition Yposition Zposition`` + 3 rotations; others: 3
    rotations; leaves get an ``End Site`` (zero offset).
    """
    names = [str(n) for n in joint_names]
    parents = np.asarray(parents, dtype=np.int64)
    offsets = np.asarray(offsets, dtype=np.float64).reshape(-1, 3)
    root_positions = np.asarray(root_positions, dtype=np.float64)
    rot = np.asarray(rotations_deg, dtype=np.float64)
    J = len(names)
    order = order.upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise ValueError(f"order must be a permutation of XYZ, got {order!r}")
    if parents.shape != (J,) or offsets.shape != (J, 3):
        raise ValueError(f"parents {parents.shape} / offsets {offsets.shape} do not match {J} joints")
    roots = np.flatnonzero(parents < 0)
    if len(roots) != 1 or roots[0] != 0:
        raise ValueError("write_bvh needs exactly one root, joint 0")
    if np.any(parents[1:] >= np.arange(1, J)):
        raise ValueError("parents[j] must be < j")
    if rot.ndim != 3 or rot.shape[1:] != (J, 3):
        raise ValueError(f"rotations_deg must be (F, {J}, 3), got {rot.shape}")
    F = rot.shape[0]
    if root_positions.shape != (F, 3):
        raise ValueError(f"root_positions must be ({F}, 3), got {root_positions.shape}")
    if not (np.isfinite(rot).all() and np.isfinite(root_positions).all() and np.isfinite(offsets).all()):
        raise ValueError("non-finite values in the motion")
    if not scale > 0:
        raise ValueError("scale must be > 0")

    children: list[list[int]] = [[] for _ in range(J)]
    for j in range(1, J):
        children[parents[j]].append(j)
    ax = {"X": "Xrotation", "Y": "Yrotation", "Z": "Zrotation"}
    rot_ch = " ".join(ax[a] for a in order)
    fmt = f"{{:.{precision}f}}"
    out: list[str] = ["HIERARCHY"]
    dfs: list[int] = []

    def emit(j, depth):
        ind = "\t" * depth
        dfs.append(j)
        if j == 0:
            out.append(f"ROOT {names[j]}")
            out.append("{")
            out.append(f"{ind}\tOFFSET 0.000000 0.000000 0.000000")
            out.append(f"{ind}\tCHANNELS 6 Xposition Yposition Zposition {rot_ch}")
        else:
            out.append(f"{ind}JOINT {names[j]}")
            out.append(f"{ind}{{")
            o = offsets[j] / scale
            out.append(f"{ind}\tOFFSET " + " ".join(fmt.format(v) for v in o))
            out.append(f"{ind}\tCHANNELS 3 {rot_ch}")
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:
            out.append(f"{ind}\tEnd Site")
            out.append(f"{ind}\t{{")
            out.append(f"{ind}\t\tOFFSET 0.000000 0.000000 0.000000")
            out.append(f"{ind}\t}}")
        out.append(f"{ind}}}")

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 4 * J + 100))
    try:
        emit(0, 0)
    finally:
        sys.setrecursionlimit(limit)
    out.append("MOTION")
    out.append(f"Frames: {F}")
    out.append(f"Frame Time: {frame_time:.7f}")
    table = np.concatenate([root_positions / scale, rot[:, dfs].reshape(F, -1)], axis=1)
    table = np.where(np.abs(table) < 0.5 * 10.0 ** -precision, 0.0, table)  # no "-0.000000"
    row_fmt = " ".join([fmt] * table.shape[1])
    body = "\n".join(row_fmt.format(*r) for r in table.tolist())
    with atomic_output(path) as tmp:
        with open(tmp, "w", encoding="ascii", newline="\n") as fh:
            fh.write("\n".join(out) + "\n" + body + ("\n" if F else ""))
