"""MakeHuman proxy fitting (.mhclo), the peer method for dressing.

A ``.mhclo`` item vertex is ``P = wi B[i] + wj B[j] + wk B[k] + (sx dx, sy dy, sz dz)``
with ``B`` the (morphed, rest-pose) base mesh INCLUDING helper vertices and
per-axis scales ``s = |B[a].c - B[b].c| / d`` from the ``x/y/z_scale`` lines.
MakeHuman units: decimetres, Y up. :func:`to_internal` maps to metres Y up
(``0.1 * (x, y, z)``), which is where :func:`usd_io.read_character` puts the
Z-up USD bodies of the data set.
"""
from __future__ import annotations

import gzip
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wearfit_usd.errors import InputError

N_BODY = 13380  # hm08 skin vertices (the rest are helpers and joint cubes)


@dataclass
class Proxy:
    name: str
    refs: np.ndarray      # (M, 3) int base-mesh vertex indices
    weights: np.ndarray   # (M, 3)
    offsets: np.ndarray   # (M, 3) decimetres
    scales: dict = field(default_factory=dict)  # axis -> (i, j, d)
    delete_verts: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    z_depth: int = 0
    obj_file: str = ""


def read_mhclo(path) -> Proxy:
    """Parse a .mhclo file (vertex lines with 3 refs or 1 ref)."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "file not found")
    name, obj, zd = path.stem, "", 0
    scales = {}
    refs, wts, offs, delete = [], [], [], []
    mode = None
    for ln, raw in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        tok = line.split()
        key = tok[0]
        if mode == "verts" and (key[0].isdigit() or key[0] == "-") and len(tok) in (1, 9):
            if len(tok) == 9:
                refs.append([int(t) for t in tok[:3]])
                wts.append([float(t) for t in tok[3:6]])
                offs.append([float(t) for t in tok[6:9]])
            else:
                refs.append([int(tok[0])] * 3)
                wts.append([1.0, 0.0, 0.0])
                offs.append([0.0, 0.0, 0.0])
            continue
        if mode == "delete" and (key[0].isdigit() or key == "-"):
            nums = line.replace("-", " - ").split()
            i = 0
            while i < len(nums):
                if i + 2 < len(nums) and nums[i + 1] == "-":
                    delete.extend(range(int(nums[i]), int(nums[i + 2]) + 1))
                    i += 3
                else:
                    if nums[i] != "-":
                        delete.append(int(nums[i]))
                    i += 1
            continue
        if key == "verts":
            mode = "verts"
        elif key == "delete_verts":
            mode = "delete"
        elif key == "name" and len(tok) > 1:
            name = tok[1]
        elif key == "obj_file" and len(tok) > 1:
            obj = tok[1]
        elif key == "z_depth" and len(tok) > 1:
            zd = int(float(tok[1]))
        elif key in ("x_scale", "y_scale", "z_scale"):
            if len(tok) != 4:
                raise InputError(path, f"{key} needs 3 values", line=ln)
            scales[key[0]] = (int(tok[1]), int(tok[2]), float(tok[3]))
    if not refs:
        raise InputError(path, "no vertex lines after 'verts'")
    return Proxy(name=name, refs=np.array(refs, dtype=np.int64), weights=np.array(wts),
                 offsets=np.array(offs), scales=scales,
                 delete_verts=np.array(sorted(set(delete)), dtype=np.int64), z_depth=zd,
                 obj_file=obj)


def fit(proxy: Proxy, base: np.ndarray) -> np.ndarray:
    """Fitted item vertices (M, 3) on base-mesh points ``base`` (V, 3), in the
    base mesh's units (decimetres)."""
    base = np.asarray(base, dtype=np.float64)
    if proxy.refs.max() >= len(base):
        raise ValueError(f"{proxy.name}: references vertex {int(proxy.refs.max())} but the base "
                         f"mesh has {len(base)} (helper vertices missing?)")
    s = np.ones(3)
    for ax, c in (("x", 0), ("y", 1), ("z", 2)):
        if ax in proxy.scales:
            i, j, d = proxy.scales[ax]
            s[c] = abs(base[i, c] - base[j, c]) / d
    return np.einsum("mk,mkc->mc", proxy.weights, base[proxy.refs]) + proxy.offsets * s


def read_obj_points(path) -> np.ndarray:
    """All ``v`` lines of an OBJ file (V, 3)."""
    pts = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.startswith("v "):
                pts.append(line.split()[1:4])
    return np.array(pts, dtype=np.float64)


def read_obj_faces(path) -> np.ndarray:
    """Polygons of an OBJ file, fan-triangulated (T, 3), 0-based."""
    tris = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.startswith("f "):
                idx = [int(t.split("/")[0]) - 1 for t in line.split()[1:]]
                for k in range(1, len(idx) - 1):
                    tris.append((idx[0], idx[k], idx[k + 1]))
    return np.array(tris, dtype=np.int64)


def read_target(path) -> tuple[np.ndarray, np.ndarray]:
    """A gzip shape target: (indices (P,), offsets (P, 3)) in decimetres."""
    idx, off = [], []
    with gzip.open(path, "rt") as fh:
        for line in fh:
            t = line.split()
            if len(t) == 4 and not t[0].startswith("#"):
                idx.append(int(t[0]))
                off.append([float(v) for v in t[1:]])
    return np.array(idx, dtype=np.int64), np.array(off).reshape(-1, 3)


def shape_points(makehuman_dir, shape: str) -> np.ndarray:
    """Base mesh (all vertices, helpers included) with the ``shape`` recipe of
    body_shapes.json applied, decimetres."""
    root = Path(makehuman_dir)
    recipes = json.loads((root / "body_shapes.json").read_text())
    if shape not in recipes["shapes"]:
        raise KeyError(f"unknown shape {shape!r}; known: {sorted(recipes['shapes'])}")
    pts = read_obj_points(root / recipes.get("base_mesh", "3dobjs/base.obj"))
    for rel, w in recipes["shapes"][shape]["targets"]:
        i, d = read_target(root / rel)
        if len(i):
            np.add.at(pts, i, float(w) * d)
    return pts


def to_internal(points_dm: np.ndarray) -> np.ndarray:
    """MakeHuman decimetres (Y up) -> internal metres (Y up)."""
    return 0.1 * np.asarray(points_dm, dtype=np.float64)
