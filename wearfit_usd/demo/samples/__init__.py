"""The project's own sample data: a procedural rigged body, wearable items
and BVH clips, so that ``wearfit demo`` runs without the shared data set.

Public API::

    make_body(params=None, resolution=0.014) -> Character   # mesh from scratch
    make_target(name, reference=None) -> Character          # a preset target body
    make_items(body) -> list[Mesh]                           # items on a sample body
    make_garments(body) -> list[Mesh]                        # dress, coat, hair... (issue 17)
    write_sample_set(out_dir) -> dict[str, Path]             # references + targets (.usda)
    motion_path(name) -> Path                                # packaged .bvh clip
    PRESETS, SAME_TOPOLOGY_TARGETS, REMESHED_TARGETS, BodyParams, CLIPS, GARMENT_SETS

Targets in ``SAME_TOPOLOGY_TARGETS`` share the reference's faces vertex for
vertex (morphed through the parametric model); ``REMESHED_TARGETS`` are
meshed independently at another resolution (different topology).
"""
from __future__ import annotations

import os
from pathlib import Path

from ...io.usd import write_character
from .body import PRESETS, REMESHED_TARGETS, SAME_TOPOLOGY_TARGETS, BodyParams, body_params, make_body, morph_body
from .garments import GARMENT_CLEARANCE, LOOSE_GARMENTS, make_garments
from .items import CLEARANCE, make_items

__all__ = ["PRESETS", "SAME_TOPOLOGY_TARGETS", "REMESHED_TARGETS", "BodyParams", "CLEARANCE",
           "GARMENT_CLEARANCE", "GARMENT_SETS", "LOOSE_GARMENTS", "CLIPS", "body_params", "make_body",
           "make_target", "make_items", "make_garments", "make_outfit", "write_sample_set",
           "motion_path"]

#: the garment references (one stage each, on the reference body): their
#: garments (:data:`GARMENT_CLEARANCE`) and items (:data:`CLEARANCE`) worn
#: under or with them. ``ref_loose`` holds the loose parts the demo animates.
GARMENT_SETS = {
    "ref_loose": (["dress", "long_hair"], ["shoes"]),
    "ref_coat": (["coat"], ["trousers", "shoes"]),
    "ref_suit": (["suit"], ["shoes"]),
    "ref_pencil": (["pencil_skirt"], ["undershirt", "shoes"]),
}


def __getattr__(name):
    # motions is imported lazily (here and below), so that
    # ``python3 -m wearfit_usd.demo.samples.motions`` runs cleanly
    if name == "CLIPS":
        from .motions import CLIPS
        return CLIPS
    raise AttributeError(name)


def make_target(name: str, reference=None):
    """Target body ``name`` (a key of :data:`PRESETS`, not "reference").

    Same-topology targets are morphed from ``reference`` (made when None);
    remeshed ones are meshed at their own resolution."""
    if name in REMESHED_TARGETS:
        return make_body(name, resolution=REMESHED_TARGETS[name])
    if name not in SAME_TOPOLOGY_TARGETS:
        raise KeyError(f"unknown target {name!r}; known: "
                       f"{SAME_TOPOLOGY_TARGETS + list(REMESHED_TARGETS)}")
    return morph_body(reference if reference is not None else make_body("reference"), name)


def make_outfit(body, set_name: str) -> list:
    """The items of :data:`GARMENT_SETS` ``[set_name]`` made on ``body``:
    the items worn under or with the garments first, then the garments."""
    garments, items = GARMENT_SETS[set_name]
    return make_items(body, items) + make_garments(body, garments)


def write_sample_set(out_dir, targets: list[str] | None = None,
                     garment_sets: list[str] | None = None) -> dict[str, Path]:
    """Write ``reference.usda`` (body + every item, each with its display
    colour), one ``<set>.usda`` per garment set (:data:`GARMENT_SETS`; the
    reference body wearing that outfit) and ``target_<name>.usda`` (bodies
    only) into ``out_dir``.

    Stages are Y up, metres, 30 time codes/s. Returns {"reference": path,
    "ref_loose": path, ..., "target_<name>": path, ...}.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ref = make_body("reference")
    ref.items = make_items(ref)
    paths = {"reference": write_character(out / "reference.usda", ref)}
    for set_name in (list(GARMENT_SETS) if garment_sets is None else garment_sets):
        paths[set_name] = write_character(out / f"{set_name}.usda", ref, items=make_outfit(ref, set_name))
    names = list(SAME_TOPOLOGY_TARGETS) + list(REMESHED_TARGETS) if targets is None else targets
    for name in names:
        tgt = make_target(name, ref)
        paths[f"target_{name}"] = write_character(out / f"target_{name}.usda", tgt, items=[])
    return paths


def motion_path(name: str) -> Path:
    """Path of the packaged clip ``name`` (see :data:`CLIPS`). If the package
    data is missing (e.g. a stripped install), the clips are generated into
    a cache folder (``$XDG_CACHE_HOME/wearfit_usd/motions``) first."""
    from .motions import CLIPS
    if name not in CLIPS:
        raise KeyError(f"unknown sample motion {name!r}; known: {CLIPS}")
    pkg = Path(__file__).resolve().parents[2] / "motions" / f"{name}.bvh"
    if pkg.exists():
        return pkg
    from .motions import write_clips
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "wearfit_usd" / "motions"
    target = cache / f"{name}.bvh"
    if not target.exists():
        write_clips([cache])
    return target
