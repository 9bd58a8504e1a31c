"""Fit maps: colour items by their clearance to the body, with a legend.

Clearance = signed distance from each item vertex to the body surface
(metres, positive outside the body), from :mod:`wearfit_usd.clearance`
(imported lazily). Two maps:

* ``"clearance"``: penetrating (magenta) -> tight (red) -> orange -> yellow
  -> green -> loose (blue), like commercial garment fit maps;
* ``"change"``: clearance minus a reference's clearance for the same item
  vertices: tighter (red) -> unchanged (light grey) -> looser (blue).
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError

# (value in metres, sRGB colour)
CLEARANCE_STOPS = [
    (-0.008, (0.50, 0.02, 0.45)),   # penetrating
    (0.000, (0.86, 0.10, 0.12)),    # tight / touching
    (0.008, (0.97, 0.50, 0.10)),
    (0.018, (0.98, 0.86, 0.22)),
    (0.035, (0.42, 0.76, 0.36)),
    (0.060, (0.18, 0.44, 0.84)),    # loose
]
CHANGE_STOPS = [
    (-0.020, (0.80, 0.08, 0.10)),   # tighter than the reference
    (-0.006, (0.95, 0.60, 0.45)),
    (0.000, (0.90, 0.90, 0.90)),    # unchanged
    (0.006, (0.55, 0.70, 0.92)),
    (0.020, (0.10, 0.32, 0.80)),    # looser
]
MAPS = {"clearance": CLEARANCE_STOPS, "change": CHANGE_STOPS}
TITLES = {"clearance": "clearance (mm)", "change": "change vs ref (mm)"}
END_LABELS = {"clearance": ("penetrating", "loose"), "change": ("tighter", "looser")}


def colormap(values: np.ndarray, kind: str = "clearance") -> np.ndarray:
    """(M,) metres -> (M, 3) sRGB 0-1, piecewise linear between the stops,
    clamped at both ends."""
    stops = MAPS[kind]
    xs = np.array([s[0] for s in stops])
    cs = np.array([s[1] for s in stops])
    v = np.asarray(values, dtype=np.float64)
    return np.stack([np.interp(v, xs, cs[:, k]) for k in range(3)], axis=-1)


class ClearanceField:
    """Signed clearance of item vertices to a (moving) body surface.

    body_faces (T, 3); call :meth:`__call__` with body points (N, 3) and item
    points (M, 3); the body's search structure is rebuilt only when the body
    points array object changes."""

    def __init__(self, body_faces: np.ndarray):
        from ..geometry.closest import SurfaceQuery  # lazy: heavy and optional
        self._query = SurfaceQuery(np.asarray(body_faces, dtype=np.int64))
        self._body_obj = None

    def __call__(self, body_points: np.ndarray, item_points: np.ndarray) -> np.ndarray:
        if body_points is not self._body_obj:
            self._query.update(np.asarray(body_points, dtype=np.float64))
            self._body_obj = body_points
        return self._query.signed_distance(np.asarray(item_points, dtype=np.float64))


def reference_clearance(scene, reference) -> dict[str, np.ndarray]:
    """Per item name, the clearance (M,) of the reference scene's item at its
    first frame. Items are matched by name and must have the same vertex
    count as in ``scene``; raises InputError naming the mismatch."""
    if reference.body is None:
        raise InputError(reference.source, "the reference stage has no body mesh")
    field = ClearanceField(reference.body.faces)
    ref_items = {m.name: m for m in reference.items}
    out = {}
    for item in scene.items:
        r = ref_items.get(item.name)
        if r is None:
            raise InputError(reference.source, f"reference has no item named {item.name!r} "
                                               f"(it has {sorted(ref_items)})")
        if r.n_points != item.n_points:
            raise InputError(reference.source, f"item {item.name!r} has {r.n_points} points in the "
                                               f"reference but {item.n_points} here")
        out[item.name] = field(reference.body.frames[0], r.frames[0])
    return out


def draw_legend(image: np.ndarray, kind: str = "clearance", stats: str | None = None) -> np.ndarray:
    """Draw a vertical colour bar with millimetre ticks into the right edge of
    an (H, W, 3) uint8 image; returns a new array."""
    from PIL import Image, ImageDraw, ImageFont
    img = Image.fromarray(np.asarray(image)[:, :, :3].copy())
    h, w = img.height, img.width
    scale = max(0.6, min(w, h) / 480)
    try:
        font = ImageFont.load_default(size=max(9, int(12 * scale)))
    except TypeError:  # Pillow < 10.1
        font = ImageFont.load_default()
    stops = MAPS[kind]
    lo, hi = stops[0][0], stops[-1][0]
    bar_w = int(16 * scale)
    bar_h = int(h * 0.5)
    x0 = w - int(70 * scale)
    y0 = int((h - bar_h) / 2)
    vals = np.linspace(hi, lo, bar_h)  # top = high value
    col = (colormap(vals, kind) * 255).round().astype(np.uint8)
    bar = np.repeat(col[:, None, :], bar_w, axis=1)
    img.paste(Image.fromarray(bar), (x0, y0))
    d = ImageDraw.Draw(img)
    d.rectangle([x0 - 1, y0 - 1, x0 + bar_w, y0 + bar_h], outline=(60, 60, 60))
    for v, _ in stops:
        y = y0 + int(round((hi - v) / (hi - lo) * (bar_h - 1)))
        d.line([x0 + bar_w, y, x0 + bar_w + 4, y], fill=(60, 60, 60))
        d.text((x0 + bar_w + 6, y - 6 * scale), f"{v * 1000:+.0f}" if kind == "change" else
               f"{v * 1000:.0f}", fill=(40, 40, 40), font=font)
    title = TITLES[kind]
    tw = d.textlength(title, font=font)
    d.text((min(x0 - 4, w - tw - 4), y0 - 20 * scale), title, fill=(40, 40, 40), font=font)
    low, high = END_LABELS[kind]
    d.text((min(x0 - 4, w - d.textlength(high, font=font) - 4), y0 - 36 * scale), high,
           fill=(40, 40, 40), font=font)
    d.text((min(x0 - 4, w - d.textlength(low, font=font) - 4), y0 + bar_h + 4 * scale), low,
           fill=(40, 40, 40), font=font)
    if stats:
        d.text((int(8 * scale), h - int(18 * scale)), stats, fill=(40, 40, 40), font=font)
    return np.asarray(img)
