"""Render a stage: scene description -> camera -> images -> files.

:func:`render_frames` is the Python entry point (images as numpy arrays);
:func:`render_to_dir` adds the files the CLI writes.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..progress import progress
from .camera import TRACK_SMOOTHING_S, frame_box, parse_camera, should_track, tracking_views, turntable_box
from .lighting import HEATMAP_BODY_COLOR
from .scene import SceneDescription, read_scene


def _parse_size(size) -> tuple[int, int]:
    if isinstance(size, str):
        a, sep, b = size.lower().partition("x")
        if not sep:
            raise ValueError(f"bad size {size!r}: expected WIDTHxHEIGHT, e.g. 640x480")
        size = (int(a), int(b))
    w, h = int(size[0]), int(size[1])
    if not (8 <= w <= 8192 and 8 <= h <= 8192):
        raise ValueError(f"bad size {w}x{h}: each side must be 8..8192 pixels")
    return w, h


def resolve_track(scene: SceneDescription, camera: str = "auto", track: bool | None = None) -> bool:
    """Whether :func:`render_scene` follows the character: never for a
    turntable; ``track`` when given; else (None) when the character's
    horizontal travel over the frames exceeds half its height
    (:func:`~.camera.should_track`). Raises ValueError for a bad camera."""
    kind, _ = parse_camera(camera)
    if kind == "turntable" or scene.n_frames < 2 or not scene.meshes:
        return False
    if track is not None:
        return bool(track)
    return should_track(*scene.frame_bounds())


#: items are drawn this far (metres) proud of their true surface, outward
#: from the body (display only): tight, low-poly garments let the curved
#: skin bulge through between their vertices (MakeHuman hides the skin under
#: clothes instead). Measurements and heat maps use the true points.
ITEM_DISPLAY_OFFSET = 0.003


def _outward_offsets(scene: SceneDescription, offset: float):
    """Per item mesh: +1/-1 so that its vertex normals point away from the
    body (decided once, on the first frame), or None without a body."""
    from ..geometry.closest import SurfaceQuery, VertexNormals
    body = scene.body
    if body is None or offset <= 0:
        return {}
    q = SurfaceQuery(body.faces, body.frames[0])
    signs = {}
    for m in scene.items:
        if len(m.faces) == 0:
            continue
        normals = VertexNormals(m.faces, m.n_points)
        away = m.frames[0] - q.closest(m.frames[0])["point"]
        sign = 1.0 if np.einsum("ij,ij->", normals(m.frames[0]), away) >= 0 else -1.0
        signs[id(m)] = (sign, normals)
    return signs


def render_scene(scene: SceneDescription, size=(640, 480), camera: str = "auto",
                 heatmap: bool = False, reference: SceneDescription | None = None,
                 antialias: bool = False, show_progress: bool = True,
                 legend: bool = True, track: bool | None = None,
                 item_offset: float = ITEM_DISPLAY_OFFSET) -> list[np.ndarray]:
    """Render a :class:`SceneDescription` to (H, W, 3) uint8 images.

    camera: ``front|side|back|auto`` (one image per scene frame) or
    ``turntable:N`` (N images around the scene's first frame). track: with a
    named view, True makes the camera follow the character (fixed
    orientation, distance and height; target on the smoothed horizontal
    centre of the per-frame boxes, distance sized to the largest per-frame
    box), False keeps one fixed camera framing the character over all
    frames, None (default) tracks when the character travels more than half
    its height (:func:`resolve_track`). heatmap: colour items by clearance to
    the body (``reference``: by change of clearance versus the reference
    scene's items). item_offset: items drawn this far (metres) outward from
    the body, display only (see :data:`ITEM_DISPLAY_OFFSET`; 0 = exact).
    Raises ValueError for bad camera/size."""
    from .offscreen import Renderer
    w, h = _parse_size(size)
    kind, angles = parse_camera(camera)
    track = resolve_track(scene, camera, track)
    if heatmap or reference is not None:
        heatmap = True
        if scene.body is None or not scene.items:
            raise InputError(scene.source, "a heatmap needs a body and at least one item mesh")
    if kind == "turntable":
        frame_ids = [0] * len(angles)
        lo, hi = turntable_box(*scene.bounds([0]))
        views = [frame_box(lo, hi, yaw, el, w / h) for yaw, el in angles]
    elif track:
        frame_ids = list(range(scene.n_frames))
        los, his = scene.frame_bounds()
        sigma = TRACK_SMOOTHING_S * (scene.fps if scene.fps and scene.fps > 0 else 24.0)
        views = tracking_views(los, his, scene.times, angles[0][0], angles[0][1], w / h, sigma)
    else:
        frame_ids = list(range(scene.n_frames))
        lo, hi = scene.bounds()
        views = [frame_box(lo, hi, angles[0][0], angles[0][1], w / h)] * len(frame_ids)

    field = ref_clear = None
    map_kind = "clearance"
    if heatmap:
        from .heatmap import ClearanceField, colormap, draw_legend, reference_clearance
        field = ClearanceField(scene.body.faces)
        if reference is not None:
            ref_clear = reference_clearance(scene, reference)
            map_kind = "change"

    images = []
    r = Renderer((w, h), antialias=antialias)
    try:
        handles = []
        for m in scene.meshes:
            colored = heatmap and m.role == "item"
            color = HEATMAP_BODY_COLOR if heatmap and m.role == "body" else m.color
            handles.append(r.add_mesh(m.name, m.frames[0], m.faces, color=color,
                                      vertex_colors=np.ones((m.n_points, 3)) if colored else None))
        it = zip(frame_ids, views)
        if show_progress:
            it = progress(it, total=len(frame_ids), desc="render", unit="frame")
        last_view = None
        last_heat_frame = None
        outward = _outward_offsets(scene, item_offset)
        for fi, view in it:
            for hd, m in zip(handles, scene.meshes):
                pts = m.frames[fi]
                if id(m) in outward:
                    sign, normals = outward[id(m)]
                    pts = pts + (sign * item_offset) * normals(pts)
                r.set_points(hd, pts)
            stats = None
            if heatmap and fi != last_heat_frame:
                last_heat_frame = fi
                body_pts = scene.body.frames[fi]
                worst = []
                for hd, m in zip(handles, scene.meshes):
                    if m.role != "item":
                        continue
                    c = field(body_pts, m.frames[fi])
                    worst.append(float(c.min()))
                    if ref_clear is not None:
                        c = c - ref_clear[m.name]
                    r.set_colors(hd, colormap(c, map_kind))
                stats = f"min clearance {min(worst) * 1000:.1f} mm"
            if view is not last_view:
                r.set_view(view)
                last_view = view
            img = r.render()
            if heatmap and legend:
                img = draw_legend(img, map_kind, stats if map_kind == "clearance" else None)
            images.append(img)
    finally:
        r.close()
    return images


def render_frames(stage_path, frames=None, size=(640, 480), camera: str = "auto",
                  heatmap: bool = False, heatmap_against=None, antialias: bool = False,
                  show_progress: bool = True, track: bool | None = None) -> list[np.ndarray]:
    """Render a USD stage to a list of (H, W, 3) uint8 images.

    frames: None (the stage's whole time range), ``(start, end)`` inclusive
    time codes or ``"A:B"``. size: (width, height) or ``"640x480"``.
    camera: ``front|side|back|auto|turntable:N``. track: camera follows the
    character (True), one fixed camera (False), or None = follow when it
    travels more than half its height (see :func:`render_scene`). heatmap: colour items by
    clearance to the body; heatmap_against: path of a reference stage to
    colour by change of clearance instead.
    Raises :class:`~wearfit_usd.errors.InputError` for bad input."""
    try:
        _parse_size(size)
        parse_camera(camera)
    except ValueError as exc:
        raise InputError(stage_path, str(exc)) from None
    scene = read_scene(stage_path, frames)
    reference = read_scene(heatmap_against, None) if heatmap_against is not None else None
    return render_scene(scene, size=size, camera=camera, heatmap=heatmap, reference=reference,
                        antialias=antialias, show_progress=show_progress, track=track)


def render_to_dir(stage_path, out_dir, frames=None, size=(640, 480), camera: str = "auto",
                  gif: bool = False, mp4: bool = False, heatmap: bool = False,
                  heatmap_against=None, fps: float | None = None, antialias: bool = False,
                  show_progress: bool = True, track: bool | None = None) -> dict:
    """Render and write ``out_dir/frame_0000.png ...``, ``contact_sheet.png``
    and optionally ``preview.gif`` / ``preview.mp4``. fps: default the
    stage's time codes per second (turntables: 12). track: as in
    :func:`render_frames` (None = automatic). Returns the written paths,
    ``n_frames``, ``times`` and ``tracked`` (whether the camera followed)."""
    from .media import write_outputs
    try:
        _parse_size(size)
        kind, _ = parse_camera(camera)
    except ValueError as exc:
        raise InputError(stage_path, str(exc)) from None
    if fps is not None and not fps > 0:
        raise InputError(stage_path, f"fps must be > 0, got {fps}")
    scene = read_scene(stage_path, frames)
    reference = read_scene(heatmap_against, None) if heatmap_against is not None else None
    tracked = resolve_track(scene, camera, track)
    images = render_scene(scene, size=size, camera=camera, heatmap=heatmap, reference=reference,
                          antialias=antialias, show_progress=show_progress, track=tracked)
    if fps is None:
        fps = 12.0 if kind == "turntable" else (scene.fps or 24.0)
    out = write_outputs(images, Path(out_dir), fps=fps, gif=gif, mp4=mp4)
    out["n_frames"] = len(images)
    out["times"] = scene.times if kind != "turntable" else [scene.times[0]]
    out["tracked"] = tracked
    return out
