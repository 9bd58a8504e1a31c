"""USD edge: read rigged characters into the numpy model, write results back.

Reading: :func:`read_character` finds the skinned body (the Mesh bound to a
Skeleton through ``skel:skeleton``; if several, the one with most points) and
treats every other Mesh as a wearable item. Everything is returned in
internal space (world, metres, Y up); see :mod:`wearfit_usd.model`.

Writing: :func:`write_character` authors a static rigged stage (body +
items); :class:`ShotWriter` authors an animated shot (SkelAnimation + items
with time-sampled points), frame by frame (:mod:`.usd_shot`). Both author
through :mod:`.usd_author` and write to a temporary file in the destination
folder renamed into place (:mod:`.atomic`), so a crash never leaves a
half-written file.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..errors import GeometryError, InputError, USDInputError, WriteError
from ..geometry.body_parts import body_parts
from ..model import Character, Mesh, Primvar, Skeleton, merge_meshes, without_skinned_copies
from ..progress import info, warn
from ..transforms import invert, stage_to_internal, transform_points
from .atomic import atomic_output
from .gltf import is_gltf, read_gltf_character
from .usd_author import StageLayout, author_body, author_skeleton, author_static_item
from .usd_carry import CarryPlan, carry

_SKIP_PRIMVARS = {"skel:jointIndices", "skel:jointWeights", "skel:geomBindTransform",
                  "skel:skinningMethod"}


def _pxr():
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt  # noqa: F401
    return Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt


def _np(value, dtype=np.float64) -> np.ndarray:
    return np.array(value, dtype=dtype)


def _get(path, attr, time=None):
    """``attr.Get(time)``, None when unauthored; :class:`USDInputError` for
    a value USD parsed but could not type (e.g. an out-of-range number)."""
    v = attr.Get() if time is None else attr.Get(time)
    if v is not None and type(v).__name__ == "UnregisteredValue":
        where = attr.GetAttr() if hasattr(attr, "GetAttr") else attr  # a primvar or an attribute
        raise USDInputError(path, f"{where.GetPath()}: malformed value (out of range or wrong type)")
    return v


# --------------------------------------------------------------------------
# topology helpers (pure numpy)

def triangulate(face_vertex_counts: np.ndarray, face_vertex_indices: np.ndarray,
                left_handed: bool = False):
    """Fan-triangulate polygons.

    Returns ``faces`` (T, 3) int64 and ``tri_to_poly`` (T,) int64. Polygons
    with fewer than 3 vertices are skipped. With ``left_handed`` the winding is
    reversed so that triangles are always counter-clockwise from outside.
    """
    counts = np.asarray(face_vertex_counts, dtype=np.int64)
    idx = np.asarray(face_vertex_indices, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ntri = np.maximum(counts - 2, 0)
    poly = np.repeat(np.arange(len(counts)), ntri)
    # k-th triangle of polygon: (v0, v_{k+1}, v_{k+2})
    first = np.repeat(starts, ntri)
    k = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    faces = np.stack([idx[first], idx[first + k + 1], idx[first + k + 2]], axis=1)
    if left_handed:
        faces = faces[:, ::-1].copy()
    return faces, poly


def _check_points(path, name, pts):
    if pts.size == 0:
        raise GeometryError(path, f"mesh {name} has no points")
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise GeometryError(path, f"mesh {name} has {int(bad.sum())} NaN/inf points "
                                  f"(first at index {int(np.argmax(bad))})")


# --------------------------------------------------------------------------
# reading

def open_stage(path):
    """Open a USD stage, with a clear error if it cannot be read."""
    _, _, Usd, _, _, _ = _pxr()
    p = Path(path)
    if not p.exists():
        raise InputError(path, "file not found")
    try:
        stage = Usd.Stage.Open(str(p))
    except Exception as exc:  # pxr raises Tf.ErrorException
        raise USDInputError(path, f"cannot open as USD: {str(exc).strip().splitlines()[-1]}") from None
    if stage is None:
        raise USDInputError(path, "cannot open as USD")
    return stage


def _read_mesh(stage, prim, to_internal, path, time=None) -> Mesh:
    _, _, Usd, UsdGeom, _, _ = _pxr()
    # default: the authored default value, else the earliest time sample
    t = Usd.TimeCode.EarliestTime() if time is None else Usd.TimeCode(time)
    mesh = UsdGeom.Mesh(prim)
    name = prim.GetName()
    pts_v = _get(path, mesh.GetPointsAttr(), t)
    counts_v = _get(path, mesh.GetFaceVertexCountsAttr(), t)
    idx_v = _get(path, mesh.GetFaceVertexIndicesAttr(), t)
    if pts_v is None or counts_v is None or idx_v is None or len(pts_v) == 0:
        raise GeometryError(path, f"mesh {prim.GetPath()} is empty (no points or faces)")
    pts = _np(pts_v)
    _check_points(path, prim.GetPath(), pts)
    counts = _np(counts_v, np.int64)
    idx = _np(idx_v, np.int64)
    if len(counts) == 0 or len(idx) == 0:
        raise GeometryError(path, f"mesh {prim.GetPath()} has no faces (empty faceVertexCounts)")
    if counts.min() < 3:
        raise GeometryError(path, f"mesh {prim.GetPath()}: faceVertexCounts holds {int(counts.min())} "
                                  f"at face {int(np.argmin(counts))} (every face needs >= 3 vertices)")
    if counts.sum() != len(idx):
        raise GeometryError(path, f"mesh {prim.GetPath()}: faceVertexCounts sum {counts.sum()} "
                                  f"!= {len(idx)} faceVertexIndices")
    if len(idx) and (idx.min() < 0 or idx.max() >= len(pts)):
        raise GeometryError(path, f"mesh {prim.GetPath()}: face vertex index out of range")
    left = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    faces, t2p = triangulate(counts, idx, left)
    if len(faces) == 0:
        raise GeometryError(path, f"mesh {prim.GetPath()} has no polygons")
    if not (np.ptp(pts, axis=0) > 0).any():
        raise GeometryError(path, f"mesh {prim.GetPath()}: all {len(pts)} points are equal")
    xf = _np(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(t))
    world = transform_points(pts, xf @ to_internal)
    primvars = []
    color = None
    for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars():
        pname = pv.GetPrimvarName()
        if pname in _SKIP_PRIMVARS or pname.startswith("skel:"):
            continue
        val = pv.Get(t)
        if val is None:
            continue
        if pname == "displayColor":
            c = np.array(val, dtype=float).reshape(-1, 3)
            if len(c):
                color = c.mean(axis=0)
        try:
            arr = np.array(val)
        except Exception:
            continue
        ind = pv.GetIndices(t) if pv.IsIndexed() else None
        primvars.append(Primvar(pname, str(pv.GetTypeName()), pv.GetInterpolation(), arr,
                                None if ind is None else np.array(ind, dtype=np.int64),
                                pv.GetElementSize()))
    nrm_interp = None
    if mesh.GetNormalsAttr().HasAuthoredValue():
        nrm_interp = mesh.GetNormalsInterpolation()
    ds = mesh.GetDoubleSidedAttr().Get()
    return Mesh(name=name, points=world, faces=faces, face_vertex_counts=counts,
                face_vertex_indices=idx, tri_to_poly=t2p, path=str(prim.GetPath()),
                primvars=primvars, normals_interpolation=nrm_interp, left_handed=left,
                double_sided=bool(ds), display_color=color)


def _read_skeleton(skel_query, skel_prim, to_internal, path) -> Skeleton:
    _, _, Usd, UsdGeom, UsdSkel, _ = _pxr()
    skel = UsdSkel.Skeleton(skel_prim)
    topo = skel_query.GetTopology()
    joints = [str(j) for j in skel_query.GetJointOrder()]
    if not joints:
        raise USDInputError(path, f"skeleton {skel_prim.GetPath()} has no joints")
    ok, why = topo.Validate()
    if not ok:
        raise USDInputError(path, f"skeleton {skel_prim.GetPath()}: invalid joint topology: {why}")
    parents = np.array(topo.GetParentIndices(), dtype=np.int64)
    bind = _get(path, skel.GetBindTransformsAttr())
    if bind is None or len(bind) != len(joints):
        raise USDInputError(path, f"skeleton {skel_prim.GetPath()}: bindTransforms has "
                                  f"{0 if bind is None else len(bind)} entries for {len(joints)} joints")
    bind = _np(bind).reshape(-1, 4, 4)
    _check_transforms(path, skel_prim, "bindTransforms", joints, bind)
    rest = _get(path, skel.GetRestTransformsAttr())
    if rest is None or len(rest) != len(joints):
        # rest defaults to the bind pose, expressed locally
        inv = invert(bind)
        rest = np.array([bind[j] if parents[j] < 0 else bind[j] @ inv[parents[j]]
                         for j in range(len(joints))])
    else:
        rest = _np(rest).reshape(-1, 4, 4)
        _check_transforms(path, skel_prim, "restTransforms", joints, rest)
    skel_xf = _np(UsdGeom.Xformable(skel_prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    k = skel_xf @ to_internal
    _check_transforms(path, skel_prim, "transform", ["(the skeleton prim)"], k[None])
    names = [j.split("/")[-1] for j in joints]
    return Skeleton(joint_names=names, joint_paths=joints, parents=parents,
                    bind_world=bind @ k, rest_local=rest, skel_to_world=k,
                    path=str(skel_prim.GetPath()))


def _check_transforms(path, prim, what: str, joints, mats: np.ndarray) -> None:
    """Refuse NaN/inf, singular (zero-scale) and not affine (J, 4, 4) joint
    transforms, naming the first bad joint."""
    with np.errstate(all="ignore"):
        a = mats[:, :3, :3]
        finite = np.isfinite(mats).all(axis=(1, 2))
        det = np.where(finite, np.linalg.det(np.where(finite[:, None, None], a, 0.0)), 0.0)
        scale = np.abs(np.where(finite[:, None, None], a, 0.0)).max(axis=(1, 2))
        ok = finite & (np.abs(det) > 1e-12 * np.maximum(scale, 1e-300) ** 3) & (scale > 0)
    if not ok.all():
        j = int(np.argmin(ok))
        why = "NaN/inf" if not finite[j] else "a singular (zero-scale or flat) matrix"
        raise USDInputError(path, f"skeleton {prim.GetPath()}: {what} of joint {joints[j]} is {why}")


def _read_influences(skinning_query, skel: Skeleton, n_points, path, prim_path):
    """Joint indices/weights (N, K) in the skeleton's joint order, normalised."""
    ok = skinning_query.HasJointInfluences()
    if not ok:
        raise USDInputError(path, f"{prim_path}: bound to a skeleton but has no skin weights "
                                  "(primvars:skel:jointIndices/jointWeights)")
    ind_pv = skinning_query.GetJointIndicesPrimvar()
    w_pv = skinning_query.GetJointWeightsPrimvar()
    ind = _np(_get(path, ind_pv), np.int64)
    w = _np(_get(path, w_pv))
    k = skinning_query.GetNumInfluencesPerComponent()
    if len(ind) != len(w):
        raise USDInputError(path, f"{prim_path}: jointIndices has {len(ind)} values but "
                                  f"jointWeights has {len(w)}")
    if skinning_query.IsRigidlyDeformed():
        if len(ind) != k:
            raise USDInputError(path, f"{prim_path}: constant skin weights need {k} values, got {len(ind)}")
        ind = np.tile(ind, (n_points, 1))
        w = np.tile(w, (n_points, 1))
    else:
        if len(ind) != n_points * k:
            raise USDInputError(path, f"{prim_path}: {len(ind)} skin weights for {n_points} points "
                                      f"with elementSize {k} (expected {n_points * k})")
        ind = ind.reshape(n_points, k)
        w = w.reshape(n_points, k)
    if not np.isfinite(w).all():
        raise USDInputError(path, f"{prim_path}: NaN/inf skin weights")
    order = skinning_query.GetJointOrder()
    if order:
        local = [str(j) for j in order]
        lookup = {j: i for i, j in enumerate(skel.joint_paths)}
        missing = [j for j in local if j not in lookup]
        if missing:
            raise USDInputError(path, f"{prim_path}: skel:joints names {len(missing)} joints the "
                                      f"skeleton lacks, e.g. {missing[:3]}")
        remap = np.array([lookup[j] for j in local], dtype=np.int64)
        if ind.size and (ind.min() < 0 or ind.max() >= len(remap)):
            raise USDInputError(path, f"{prim_path}: joint index out of range of its skel:joints")
        ind = remap[ind]
    elif ind.size and (ind.min() < 0 or ind.max() >= skel.n_joints):
        raise USDInputError(path, f"{prim_path}: joint index {int(ind.max())} out of range "
                                  f"({skel.n_joints} joints)")
    w = np.where(w < 0, 0.0, w)
    s = w.sum(axis=1, keepdims=True)
    zero = s[:, 0] <= 1e-12
    if zero.any():
        raise USDInputError(path, f"{prim_path}: {int(zero.sum())} points have all-zero skin weights")
    return ind, w / s


def find_skinned_meshes(stage):
    """[(mesh prim, skel prim, skinning query, skel query)] for every skinned mesh."""
    _, _, Usd, UsdGeom, UsdSkel, _ = _pxr()
    cache = UsdSkel.Cache()
    pred = Usd.PrimDefaultPredicate
    out = []
    for root in stage.Traverse():
        if not root.IsA(UsdSkel.Root):
            continue
        cache.Populate(UsdSkel.Root(root), pred)
        for binding in cache.ComputeSkelBindings(UsdSkel.Root(root), pred):
            skel = binding.GetSkeleton()
            sq = cache.GetSkelQuery(skel)
            if not sq:
                joints = skel.GetJointsAttr().Get() or []
                raise USDInputError(stage.GetRootLayer().identifier,
                                    f"skeleton {skel.GetPrim().GetPath()}: invalid joint list "
                                    f"({len(joints)} joints): every joint must come after its parent "
                                    "and name an existing parent path")
            for target in binding.GetSkinningTargets():
                prim = target.GetPrim()
                if prim.IsA(UsdGeom.Mesh):
                    out.append((prim, skel.GetPrim(), target, sq))
    return out


def read_character(path, body_path: str | None = None, item_paths: list[str] | None = None,
                   require_skeleton: bool = True, skinned_copies: bool = False) -> Character:
    """Read a rigged body and its wearable items from a USD file (or a
    ``.glb``/``.gltf`` file, through :func:`.gltf.read_gltf_character`).

    body_path: prim path of the body mesh (default: the skinned mesh with most
        points). item_paths: prim paths of the items (default: every other
        Mesh). With ``require_skeleton=False`` a stage without any skinned mesh
        is accepted: the largest mesh becomes the body and ``skeleton`` is None.
        An item written twice (``--items both``: ``<item>`` and
        ``<item>_skinned``) is read once, as ``<item>``, unless
        ``skinned_copies`` (then both).
    """
    try:
        if is_gltf(path):  # .glb / .gltf characters (io.gltf)
            char = read_gltf_character(path, body_path, item_paths, require_skeleton)
        else:
            char = _read_character(path, body_path, item_paths, require_skeleton)
    except InputError:
        raise
    except Exception as exc:
        if not type(exc).__module__.startswith("pxr"):
            raise
        # pxr.Tf.ErrorException: a corrupt or truncated file (e.g. a crate
        # file's LZ4 blocks) found while reading values
        lines = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip()]
        why = lines[-1].split(": '", 1)[-1].rstrip("'") if lines else type(exc).__name__
        raise USDInputError(path, f"cannot read (corrupt or truncated file?): {why}") from None
    if item_paths is None and not skinned_copies:  # a `--items both` output: each item once
        keep = without_skinned_copies([m.name for m in char.items])
        char = dataclasses.replace(char, items=[m for m, k in zip(char.items, keep) if k])
    b = char.body.points
    ext = np.ptp(b, axis=0)
    if len(b) < 4 or not ext.min() > 1e-3 * ext.max():
        raise GeometryError(path, f"body {char.body.path}: {len(b)} points spanning "
                                  f"{' x '.join(f'{e:.3g}' for e in ext)} m: flat or too small to be a body")
    return char


def stage_units(stage, path) -> tuple[str, float]:
    """The stage's up axis and metres per unit, checked: a metersPerUnit
    that is not a positive finite number is an error; a root layer that
    authors neither (USD reads stage metadata from the root layer only, never
    from sublayers) gets a warning saying what is assumed."""
    _, _, _, UsdGeom, _, _ = _pxr()
    up = str(UsdGeom.GetStageUpAxis(stage))
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not (np.isfinite(mpu) and mpu > 0):
        raise USDInputError(path, f"metersPerUnit must be a positive number, got {mpu:g}")
    if up not in ("Y", "Z"):
        raise USDInputError(path, f"upAxis must be Y or Z, got {up!r}")
    missing = [k for k in ("upAxis", "metersPerUnit") if not stage.HasAuthoredMetadata(k)]
    if missing:
        subs = stage.GetRootLayer().subLayerPaths
        note = " (its sublayers' stage metadata does not count in USD)" if len(subs) else ""
        warn(f"{path}: the root layer sets no {' or '.join(missing)}{note}; assuming "
             f"upAxis {up} and metersPerUnit {mpu:g}")
    return up, mpu


def _read_character(path, body_path, item_paths, require_skeleton) -> Character:
    _, _, Usd, UsdGeom, UsdSkel, _ = _pxr()
    stage = open_stage(path)
    up, mpu = stage_units(stage, path)
    to_int = stage_to_internal(up, mpu)
    meshes = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    if not meshes:
        raise USDInputError(path, "the stage holds no Mesh prims")
    skinned = find_skinned_meshes(stage)

    def npts(prim):
        v = UsdGeom.Mesh(prim).GetPointsAttr().Get()
        return 0 if v is None else len(v)

    chosen = parts = None
    if body_path is not None:
        prim = stage.GetPrimAtPath(body_path)
        if not prim or not prim.IsA(UsdGeom.Mesh):
            raise USDInputError(path, f"no Mesh at body path {body_path}")
        chosen = next((s for s in skinned if s[0].GetPath() == prim.GetPath()), None)
        if chosen is None and require_skeleton:
            raise USDInputError(path, f"{body_path} is not bound to a skeleton (skel:skeleton)")
        body_prim = prim
    elif skinned:
        chosen = max(skinned, key=lambda s: npts(s[0]))
        body_prim = chosen[0]
        if len(skinned) > 1:
            chosen, parts = _body_parts(stage, skinned, to_int, path)
            body_prim = chosen[0]
    else:
        if require_skeleton:
            raise USDInputError(path, "no skinned mesh: no Mesh is bound to a Skeleton through "
                                      "skel:skeleton under a SkelRoot")
        body_prim = max(meshes, key=npts)

    skeleton = None
    skel_root = ""
    if chosen is not None:
        prim, skel_prim, skq, sq = chosen
        skeleton = _read_skeleton(sq, skel_prim, to_int, path)
        p = prim.GetParent()
        while p and not p.IsA(UsdSkel.Root):
            p = p.GetParent()
        skel_root = str(p.GetPath()) if p else ""
        body = _read_skinned_mesh(stage, prim, skq, skeleton, path)
        if parts is not None and len(parts) > 1:
            body = merge_meshes(parts, body.name, body.path)
    else:
        body = _read_mesh(stage, body_prim, to_int, path)

    items = []
    if item_paths is not None:
        item_prims = []
        for ip in item_paths:
            prim = stage.GetPrimAtPath(ip)
            if not prim or not prim.IsA(UsdGeom.Mesh):
                raise USDInputError(path, f"no Mesh at item path {ip}")
            item_prims.append(prim)
    else:
        in_body = {m.path for m in (body.parts or [body])}
        item_prims = [p for p in meshes if str(p.GetPath()) not in in_body]
    skinned_by_path = {s[0].GetPath(): s for s in skinned}
    for prim in item_prims:
        s = skinned_by_path.get(prim.GetPath())
        if s is not None and skeleton is not None and str(s[1].GetPath()) == skeleton.path:
            items.append(_read_skinned_mesh(stage, prim, s[2], skeleton, path))
        elif s is not None:
            other = _read_skeleton(s[3], s[1], to_int, path)
            items.append(_read_skinned_mesh(stage, prim, s[2], other, path))
            items[-1].joint_indices = None  # bound to another skeleton: keep bind shape only
            items[-1].joint_weights = None
        else:
            items.append(_read_mesh(stage, prim, to_int, path))
    names = [m.name for m in items]
    for i, m in enumerate(items):  # item names must be unique for output prims
        if names.count(m.name) > 1:
            m.name = f"{m.name}_{i}"
    return Character(source=str(path), up_axis=str(up), meters_per_unit=float(mpu),
                     to_internal=to_int, skeleton=skeleton, body=body, items=items,
                     time_codes_per_second=float(stage.GetTimeCodesPerSecond()),
                     skel_root_path=skel_root)


def _body_parts(stage, skinned, to_int, path):
    """Several skinned meshes: the body is every mesh of the skeleton with
    the largest mesh that is not layered over another one
    (:func:`~wearfit_usd.geometry.body_parts.body_parts`). Returns (the
    skinned entry of the first part, [Mesh] of the parts); says what it
    chose, and warns when the body is much smaller than its skeleton."""
    by_skel: dict = {}
    for s in skinned:
        by_skel.setdefault(str(s[1].GetPath()), []).append(s)
    best = None
    for group in by_skel.values():
        skel = _read_skeleton(group[0][3], group[0][1], to_int, path)
        meshes = [_read_skinned_mesh(stage, g[0], g[2], skel, path) for g in group]
        size = max(float(np.linalg.norm(np.ptp(m.points, axis=0))) for m in meshes)
        if best is None or size > best[0]:
            best = (size, group, skel, meshes)
    _, group, skel, meshes = best
    choice = body_parts([(m.points, m.faces) for m in meshes], skel.bind_positions())
    parts = [meshes[i] for i in choice.parts]
    body_m, skel_m = choice.extent_m
    if len(parts) > 1:
        info(f"{path}: body = {len(parts)} skinned meshes of {skel.path} merged for fitting "
             f"({', '.join(m.name for m in parts[:6])}{', ...' if len(parts) > 6 else ''}; "
             f"{sum(m.n_points for m in parts)} points, {body_m:.2f} m across)")
    else:
        info(f"{path}: body = {parts[0].path} ({body_m:.2f} m across)")
    if body_m < 0.5 * skel_m:
        warn(f"{path}: the body {parts[0].path} spans {body_m:.2f} m but its skeleton "
             f"{skel_m:.2f} m: is it a fragment?")
    return group[choice.seed], parts


def _read_skinned_mesh(stage, prim, skinning_query, skeleton: Skeleton, path) -> Mesh:
    """A skinned mesh's bind-pose shape in internal space with its influences."""
    mesh = _read_mesh(stage, prim, np.eye(4), path)
    # _read_mesh applied the prim's own xform; UsdSkel ignores it for skinned
    # meshes: bind shape = points @ geomBindTransform in skeleton space.
    from pxr import Usd, UsdGeom
    pts = _np(_get(path, UsdGeom.Mesh(prim).GetPointsAttr(), Usd.TimeCode.EarliestTime()))
    gb = _np(skinning_query.GetGeomBindTransform())
    mesh.points = transform_points(pts, gb @ skeleton.skel_to_world)
    ind, w = _read_influences(skinning_query, skeleton, len(pts), path, prim.GetPath())
    mesh.joint_indices, mesh.joint_weights = ind, w
    method = skinning_query.GetSkinningMethod() if hasattr(skinning_query, "GetSkinningMethod") else None
    if method is not None and str(method) not in ("", "classicLinear"):
        warn(f"{path}: {prim.GetPath()} asks for {method} skinning; wearfit uses linear blend skinning")
    return mesh


# --------------------------------------------------------------------------
# writing

def save_layer(layer, dest) -> None:
    """``layer.Save()``, raising :class:`WriteError` (naming ``dest``, the
    file the user asked for) when USD cannot write it (disk full...)."""
    try:
        ok = layer.Save()
    except Exception as exc:  # pxr.Tf.ErrorException
        lines = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip()]
        why = lines[0].split(": '", 1)[-1].rstrip("'") if lines else str(exc)
        raise WriteError(dest, f"cannot write: {why}") from None
    if not ok:
        raise WriteError(dest, "cannot write (USD refused to save the layer)")


def write_character(path, character: Character, items: list[Mesh] | None = None,
                    body: Mesh | None = None, up_axis: str | None = None,
                    meters_per_unit: float | None = None, skinned_items: bool = False,
                    carry_plan: CarryPlan | None = None) -> Path:
    """Write a static rigged stage: SkelRoot with Skeleton + skinned body, and
    items as plain meshes under /Root/Items (or skinned inside the SkelRoot
    with ``skinned_items`` when they carry joint influences).

    Points are taken in internal space and written in the stage space given by
    ``up_axis``/``meters_per_unit`` (default: the character's own).
    ``carry_plan``: the inputs' materials, primvars, subsets and attributes
    to carry onto the written meshes (:mod:`.usd_carry`).
    Returns the written path.
    """
    _, Sdf, Usd, UsdGeom, UsdSkel, _ = _pxr()
    up = up_axis or character.up_axis
    mpu = meters_per_unit or character.meters_per_unit
    body = body or character.body
    items = character.items if items is None else items
    with atomic_output(path) as tmp:
        stage = Usd.Stage.CreateNew(tmp)
        layout = StageLayout(stage, up, mpu)
        UsdSkel.Root.Define(stage, layout.skel_root)
        skel = character.skeleton
        if skel is not None:
            author_skeleton(layout, skel)
        author_body(layout, body, skel)
        UsdGeom.Xform.Define(stage, layout.items_path)
        item_paths = {}
        for item in items:
            item_paths[item.name] = author_static_item(layout, item, skel if skinned_items else None).GetPath()
        carry(carry_plan, stage, path, layout.body_path, item_paths)
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(0)
        stage.SetTimeCodesPerSecond(character.time_codes_per_second)
        stage.SetFramesPerSecond(character.time_codes_per_second)
        save_layer(stage.GetRootLayer(), path)
    return Path(path)
