"""Read a target body from any supported file: one dispatch on the suffix.

- ``.usd``/``.usda``/``.usdc``/``.usdz``/``.glb``/``.gltf``:
  :func:`usd.read_character`, a rigged body or (``require_skeleton=False``)
  any mesh, e.g. a scan;
- ``.obj``/``.ply``: one triangle or polygon mesh (trimesh), no rig. These
  formats carry no units or up axis: the up axis is the taller of Y and Z
  (a standing body), the units follow from the height (a body of 1-2.5 units
  is in metres, 10-25 decimetres, 100-250 centimetres, 1000-2500
  millimetres); both are said in one line;

Everything is returned as a :class:`model.Character` in internal space
(metres, Y up), ``skeleton`` None for an unrigged mesh.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ..errors import GeometryError, InputError
from ..model import Character, Mesh
from ..progress import info
from ..transforms import stage_to_internal, transform_points
from .usd import read_character
from .usd_author import prim_name

USD_TARGET_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz", ".glb", ".gltf")
MESH_TARGET_SUFFIXES = (".obj", ".ply")
TARGET_SUFFIXES = USD_TARGET_SUFFIXES + MESH_TARGET_SUFFIXES

#: standing body height range (in the file's units) -> metres per unit
_UNIT_GUESSES = ((0.5, 3.0, 1.0), (5.0, 30.0, 0.1), (50.0, 300.0, 0.01), (500.0, 3000.0, 0.001))


def read_target(path, require_skeleton: bool = True) -> Character:
    """The target body of ``path`` (internal space).

    Parameters
    ----------
    path : str or Path
        A USD stage, ``.obj`` or ``.ply``.
    require_skeleton : bool
        Refuse a target without a skinned body (as before for USD; mesh
        files never have one).

    Returns
    -------
    model.Character
        ``skeleton`` None and ``items`` empty for a plain mesh.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in USD_TARGET_SUFFIXES:
        return read_character(p, require_skeleton=require_skeleton)
    if suffix in MESH_TARGET_SUFFIXES:
        if require_skeleton:
            raise InputError(p, f"a {suffix} mesh has no skeleton; use --rig-from-reference")
        return read_mesh_target(p)
    raise InputError(p, f"unsupported target format {suffix or '(no suffix)'}: use "
                        f"{', '.join(TARGET_SUFFIXES)}")


def guess_units(points: np.ndarray) -> tuple[str, float]:
    """(up axis, metres per unit) of a standing body's (N, 3) file points:
    up is Y or Z, whichever extent is larger; units from that height."""
    ext = np.ptp(points, axis=0)
    up = "Z" if ext[2] > ext[1] else "Y"
    h = float(ext[2] if up == "Z" else ext[1])
    for lo, hi, mpu in _UNIT_GUESSES:
        if lo <= h <= hi:
            return up, mpu
    raise GeometryError(None, f"cannot tell the units of a body {h:.4g} units tall (expected a standing "
                              "body of 0.5-3 m, in metres, decimetres, centimetres or millimetres)")


def read_mesh_target(path) -> Character:
    """An ``.obj``/``.ply`` body mesh as an unrigged :class:`Character`
    (units and up axis guessed, see :func:`guess_units`)."""
    p = Path(path)
    try:
        loaded = trimesh.load(str(p), force="mesh", process=False)
    except Exception as exc:
        raise InputError(p, f"cannot read the mesh: {exc}") from None
    pts = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(pts) < 4 or len(faces) == 0:
        raise GeometryError(p, f"no usable mesh ({len(pts)} points, {len(faces)} triangles)")
    if not np.isfinite(pts).all():
        raise GeometryError(p, "the mesh has non-finite (NaN/inf) points")
    try:
        up, mpu = guess_units(pts)
    except GeometryError as exc:
        raise GeometryError(p, exc.message) from None
    info(f"{p}: {len(pts)} points, {len(faces)} triangles, no skeleton; read as {up} up, "
         f"{mpu:g} m per unit")
    to_int = stage_to_internal(up, mpu)
    body = Mesh(name=prim_name(p.stem), points=transform_points(pts, to_int), faces=faces,
                face_vertex_counts=np.full(len(faces), 3, dtype=np.int64),
                face_vertex_indices=faces.ravel().copy(), tri_to_poly=np.arange(len(faces)),
                path=str(p))
    return Character(source=str(p), up_axis=up, meters_per_unit=mpu, to_internal=to_int,
                     skeleton=None, body=body, items=[])

