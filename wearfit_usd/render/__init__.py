"""Offscreen previews of USD stages (pyrender on OSMesa, EGL fallback).

Layers, kept apart like pyrender's own: :mod:`.scene` (USD stage -> numpy
scene description per time code), :mod:`.camera` / :mod:`.lighting` (views,
framing, light rig, colours), :mod:`.offscreen` (the OpenGL renderer,
:class:`~.offscreen.Renderer`), :mod:`.heatmap` (fit maps), :mod:`.media`
(PNG, contact sheet, GIF, MP4) and :mod:`.preview` (the pipeline).

Importing this package does not import OpenGL; the platform is chosen when
the first :class:`Renderer` is created.
"""
from __future__ import annotations

__all__ = ["render_frames", "render_scene", "render_to_dir", "read_scene", "Renderer"]


def __getattr__(name):
    if name in ("render_frames", "render_scene", "render_to_dir"):
        from . import preview
        return getattr(preview, name)
    if name == "read_scene":
        from .scene import read_scene
        return read_scene
    if name == "Renderer":
        from .offscreen import Renderer
        return Renderer
    raise AttributeError(name)
