"""Camera placement: named views, turntables, auto-framing and tracking (pure numpy).

Internal space (Y up, metres); characters face +Z (MakeHuman/Blender "front",
-Y in a Z-up stage). Yaw is measured around +Y from the +Z axis towards +X:
yaw 0 = front, 90 = the character's left side, 180 = back.
Matrices are row-vector 4x4 like everywhere in wearfit: rows 0-2 of
:meth:`View.camera_to_world` are the camera's right, up and backward axes
(the camera looks down its -Z, OpenGL style), row 3 its position.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# name -> (yaw degrees, elevation degrees)
NAMED_VIEWS = {
    "front": (0.0, 4.0),
    "side": (90.0, 4.0),
    "back": (180.0, 4.0),
    "auto": (28.0, 10.0),   # three-quarter front view, slightly from above
}


@dataclass
class View:
    eye: np.ndarray      # (3,)
    target: np.ndarray   # (3,)
    up: np.ndarray       # (3,)
    yfov: float          # radians
    znear: float = 0.05
    zfar: float = 100.0

    def camera_to_world(self) -> np.ndarray:
        """(4, 4) row-vector camera-to-world matrix (camera looks down -Z)."""
        return look_at(self.eye, self.target, self.up)


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Row-vector (4, 4) pose at ``eye`` whose -Z axis points at ``target``."""
    eye = np.asarray(eye, float)
    back = eye - np.asarray(target, float)
    back /= max(np.linalg.norm(back), 1e-12)
    up = np.asarray(up, float)
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-9:  # looking straight along up
        right = np.cross(np.array([0.0, 0.0, 1.0]), back)
    right /= np.linalg.norm(right)
    true_up = np.cross(back, right)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3], m[3, :3] = right, true_up, back, eye
    return m


def direction(yaw_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector from the target towards the camera."""
    y, e = math.radians(yaw_deg), math.radians(elevation_deg)
    return np.array([math.sin(y) * math.cos(e), math.sin(e), math.cos(y) * math.cos(e)])


def frame_box(lo, hi, yaw_deg: float, elevation_deg: float, aspect: float,
              yfov_deg: float = 30.0, margin: float = 1.08) -> View:
    """A view from (yaw, elevation) whose frustum holds the box [lo, hi]
    (internal metres) with ``margin`` (>1 leaves a border), the box centre in
    the image centre. aspect = width / height."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    centre = (lo + hi) / 2
    d = direction(yaw_deg, elevation_deg)
    cam = look_at(centre + d, centre)
    right, up, back = cam[0, :3], cam[1, :3], cam[2, :3]
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])]) - centre
    tv = math.tan(math.radians(yfov_deg) / 2) / margin
    th = tv * aspect
    cx, cy, cz = corners @ right, corners @ up, corners @ back
    # corner at depth (dist - cz) must satisfy |cx| <= th * (dist - cz)
    dist = float(np.max(np.maximum(cz + np.abs(cx) / th, cz + np.abs(cy) / tv)))
    dist = max(dist, 1e-3)
    radius = float(np.linalg.norm(hi - lo)) / 2
    return View(eye=centre + d * dist, target=centre, up=np.array([0.0, 1.0, 0.0]),
                yfov=math.radians(yfov_deg), znear=max(dist - radius * 1.5, dist * 0.02),
                zfar=dist + radius * 1.5 + 1.0)


def parse_camera(spec: str) -> tuple[str, list[tuple[float, float]]]:
    """``front|side|back|auto|turntable:N`` -> (kind, [(yaw, elevation), ...]).

    kind is ``"still"`` for a named view (one view per frame) or
    ``"turntable"`` (N views around one frame). Raises ValueError."""
    s = str(spec).strip().lower()
    if s in NAMED_VIEWS:
        return "still", [NAMED_VIEWS[s]]
    if s.startswith("turntable"):
        _, _, n = s.partition(":")
        try:
            count = int(n) if n else 36
        except ValueError:
            raise ValueError(f"bad camera {spec!r}: turntable:N needs an integer N") from None
        if not 1 <= count <= 3600:
            raise ValueError(f"bad camera {spec!r}: N must be 1..3600")
        elev = NAMED_VIEWS["auto"][1]
        return "turntable", [(360.0 * k / count, elev) for k in range(count)]
    raise ValueError(f"unknown camera {spec!r} (front, side, back, auto or turntable:N)")


def turntable_box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """The box swept by [lo, hi] turning around the vertical axis through its
    centre, so that one framing distance suits every turntable view."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = (lo + hi) / 2
    r = float(np.hypot(hi[0] - lo[0], hi[2] - lo[2])) / 2
    return (np.array([c[0] - r, lo[1], c[2] - r]), np.array([c[0] + r, hi[1], c[2] + r]))


# Tracking: follow a travelling character (walks) instead of framing its whole path.
TRACK_TRAVEL_RATIO = 0.5   # auto-track when horizontal travel > this x the character's height
TRACK_SMOOTHING_S = 0.4    # Gaussian sigma (seconds) of the camera path smoothing


def should_track(los, his, ratio: float = TRACK_TRAVEL_RATIO) -> bool:
    """Whether a camera should follow the character: its per-frame box
    centres (``los``/``his`` (F, 3) per-frame boxes, internal metres) span
    horizontally more than ``ratio`` x its largest per-frame height."""
    los, his = np.atleast_2d(np.asarray(los, float)), np.atleast_2d(np.asarray(his, float))
    if len(los) < 2:
        return False
    c = (los + his)[:, [0, 2]] / 2
    travel = float(np.linalg.norm(np.ptp(c, axis=0)))
    height = float(np.max(his[:, 1] - los[:, 1]))
    return travel > ratio * max(height, 1e-9)


def smooth_path(times, values, sigma: float) -> np.ndarray:
    """Smooth a sampled path by Gaussian-weighted local linear regression.

    times: (F,) sample times; values: (F, D); sigma: Gaussian width in the
    units of ``times`` (weights cut at 3 sigma). Returns (F, D). In the
    interior this is a centred Gaussian moving average (no lag, no jitter);
    near the ends the local line fit follows a steadily moving path without
    the lag (or stop) that a truncated average gives. A constant-velocity
    path is returned unchanged."""
    t = np.asarray(times, float)
    v = np.asarray(values, float).reshape(len(t), -1)
    if len(t) < 3 or not sigma > 0:
        return v.copy()
    out = np.empty_like(v)
    for i in range(len(t)):
        dt = t - t[i]
        w = np.exp(-0.5 * (dt / sigma) ** 2)
        w[np.abs(dt) > 3 * sigma] = 0.0
        w /= w.sum()
        m1 = float(w @ dt)
        var = float(w @ (dt * dt)) - m1 * m1
        mean = w @ v
        if var <= 1e-12 * max(sigma * sigma, 1e-12):
            out[i] = mean
            continue
        slope = (w @ (dt[:, None] * v) - m1 * mean) / var
        out[i] = mean - slope * m1   # the fitted line at dt = 0
    return out


def tracking_views(los, his, times, yaw_deg: float, elevation_deg: float, aspect: float,
                   sigma: float, yfov_deg: float = 30.0, margin: float = 1.08) -> list[View]:
    """One view per frame following the character horizontally.

    los/his: (F, 3) per-frame boxes (internal metres); times: (F,) time
    codes; sigma: path smoothing in time codes. Every view has the same
    orientation, distance and height (the ground stays put); its target
    follows the smoothed horizontal centre of the per-frame boxes. The
    distance frames the envelope of the per-frame boxes taken relative to
    that path (at least the largest per-frame box), so the character keeps
    a constant size and is never cut off."""
    los, his = np.asarray(los, float), np.asarray(his, float)
    path = smooth_path(times, ((los + his) / 2)[:, [0, 2]], sigma)  # (F, 2) x, z
    rel_lo = (los[:, [0, 2]] - path).min(axis=0)
    rel_hi = (his[:, [0, 2]] - path).max(axis=0)
    lo = np.array([rel_lo[0], los[:, 1].min(), rel_lo[1]])
    hi = np.array([rel_hi[0], his[:, 1].max(), rel_hi[1]])
    base = frame_box(lo, hi, yaw_deg, elevation_deg, aspect, yfov_deg, margin)
    views = []
    for x, z in path:
        off = np.array([x, 0.0, z])
        views.append(View(eye=base.eye + off, target=base.target + off, up=base.up.copy(),
                          yfov=base.yfov, znear=base.znear, zfar=base.zfar))
    return views
