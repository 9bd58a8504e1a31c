"""Soft three-point lighting placed relative to the camera, plus colours.

Lights follow the camera (a turntable keeps the same look from every side):
a key light above and to the camera's left, a weaker fill from the right and a
rim light from behind that outlines the silhouette; a low ambient term keeps
shadowed sides readable. Poses are row-vector 4x4 (see :mod:`.camera`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera import View, direction, look_at


@dataclass
class Light:
    yaw: float        # degrees, relative to the camera's yaw
    elevation: float  # degrees above the target
    intensity: float


@dataclass
class LightRig:
    lights: list[Light] = field(default_factory=list)
    ambient: float = 0.35


DEFAULT_RIG = LightRig(lights=[
    Light(yaw=-40.0, elevation=35.0, intensity=3.2),   # key
    Light(yaw=50.0, elevation=10.0, intensity=1.5),    # fill
    Light(yaw=165.0, elevation=40.0, intensity=2.2),   # rim
], ambient=0.35)


def light_poses(view: View, rig: LightRig = DEFAULT_RIG) -> list[np.ndarray]:
    """Row-vector (4, 4) poses of the rig's directional lights for a view
    (each light shines along its -Z towards the view target)."""
    back = np.asarray(view.eye, float) - np.asarray(view.target, float)
    cam_yaw = float(np.degrees(np.arctan2(back[0], back[2])))
    out = []
    for light in rig.lights:
        d = direction(cam_yaw + light.yaw, light.elevation)
        out.append(look_at(np.asarray(view.target, float) + d, view.target))
    return out


# Pleasant, distinct sRGB colours: a warm skin tone for the body and a
# palette for the items (muted, well separated in hue).
BODY_COLOR = (0.87, 0.70, 0.58)
ITEM_PALETTE = [
    (0.80, 0.38, 0.24),   # terracotta
    (0.26, 0.44, 0.68),   # denim blue
    (0.35, 0.58, 0.36),   # sage green
    (0.90, 0.72, 0.20),   # mustard
    (0.52, 0.33, 0.60),   # plum
    (0.16, 0.58, 0.60),   # teal
    (0.62, 0.20, 0.26),   # burgundy
    (0.36, 0.36, 0.40),   # charcoal
]
HEATMAP_BODY_COLOR = (0.50, 0.51, 0.54)  # mid grey avatar: light neutral items stand out


HAIR_PALETTE = [(0.30, 0.19, 0.12), (0.50, 0.27, 0.14), (0.18, 0.13, 0.10)]
FOOTWEAR_PALETTE = [(0.22, 0.22, 0.25), (0.42, 0.27, 0.17)]
_HAIR_WORDS = ("hair", "eyebrow", "eyelash", "beard", "ponytail", "bob", "short0", "long0", "braid")
_FOOT_WORDS = ("shoe", "boot", "sneaker", "sandal", "heel")


def item_colors(names: list[str]) -> list[tuple[float, float, float]]:
    """Distinct sRGB colours for items, by kind when the name tells it
    (hair and eyebrows in hair tones, footwear dark), else from the palette."""
    out, counts = [], {"hair": 0, "foot": 0, "other": 0}
    for n in names:
        low = n.lower()
        if any(w in low for w in _HAIR_WORDS):
            kind, pal = "hair", HAIR_PALETTE
        elif any(w in low for w in _FOOT_WORDS):
            kind, pal = "foot", FOOTWEAR_PALETTE
        else:
            kind, pal = "other", ITEM_PALETTE
        out.append(pal[counts[kind] % len(pal)])
        counts[kind] += 1
    return out
