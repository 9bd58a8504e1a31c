"""What an output lost against its input: the check of :mod:`.usd_carry`.

:func:`check_carried` compares, prim by prim on the composed stages (so a
copied and a referenced output are judged alike), every material binding
(resolved, per purpose, with the bound network: each shader's id, inputs and
connections), every primvar (type, interpolation, elementSize, values,
indices), every other authored attribute (values, time samples, metadata),
the GeomSubsets (family, element type, indices, bindings), applied API
schemas, purpose, visibility and prim metadata (kind, customData,
assetInfo...). The geometry the toolkit computes is left out
(:func:`usd_carry.is_geometric`). Returns human-readable lines, one per loss:
an empty list means nothing was lost.
"""
from __future__ import annotations

import numpy as np

from .usd_carry import is_geometric

_META_KEYS = ("kind", "customData", "assetInfo", "documentation", "comment", "hidden", "displayName")
_ATTR_META_SKIP = {"typeName", "custom", "variability", "default", "timeSamples", "connectionPaths",
                   "targetPaths", "spline"}
_PURPOSES = ("", "preview", "full")


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    try:
        x, y = np.asarray(a), np.asarray(b)
        if x.dtype.kind in "fciub" and y.dtype.kind in "fciub":
            return x.shape == y.shape and bool(np.array_equal(x, y))
    except Exception:
        pass
    return a == b


def _attr_losses(where, sa, da, remap=None) -> list[str]:
    out = []
    if not da:
        return [f"{where}: attribute {sa.GetName()} missing"]
    if sa.GetTypeName() != da.GetTypeName():
        out.append(f"{where}: {sa.GetName()} type {sa.GetTypeName()} -> {da.GetTypeName()}")
    from pxr import Usd
    if not _same(sa.Get(Usd.TimeCode.Default()), da.Get(Usd.TimeCode.Default())):
        out.append(f"{where}: {sa.GetName()} value differs")
    ts = sa.GetTimeSamples()
    if list(ts) != list(da.GetTimeSamples()):
        out.append(f"{where}: {sa.GetName()} time samples differ")
    else:
        for t in ts:
            if not _same(sa.Get(t), da.Get(t)):
                out.append(f"{where}: {sa.GetName()} differs at time {t}")
                break
    sm, dm = sa.GetAllMetadata(), da.GetAllMetadata()
    for k, v in sm.items():
        if k in _ATTR_META_SKIP or k not in sa.GetAllAuthoredMetadata():
            continue
        if not _same(v, dm.get(k)):
            out.append(f"{where}: {sa.GetName()} metadata {k} differs")
    if remap is not None:
        sc = [remap(c) for c in sa.GetConnections()]
        dc = [str(c) for c in da.GetConnections()]
        if sc != dc:
            out.append(f"{where}: {sa.GetName()} connections {sc} -> {dc}")
    return out


def _network_losses(where, smat, dmat) -> list[str]:
    """Material (or any prim tree) ``smat`` against ``dmat``: same prims
    (relative paths), types, attribute values and connections (relative)."""
    out = []
    sroot, droot = smat.GetPath(), dmat.GetPath()

    def rel(path):
        return str(path.ReplacePrefix(sroot, droot)) if path.HasPrefix(sroot) else f"outside:{path}"

    stack = [smat]
    while stack:
        sp = stack.pop()
        dp = dmat.GetStage().GetPrimAtPath(sp.GetPath().ReplacePrefix(sroot, droot))
        w = f"{where} material {sp.GetPath()}"
        if not dp:
            out.append(f"{w}: missing")
            continue
        if sp.GetTypeName() != dp.GetTypeName():
            out.append(f"{w}: type {sp.GetTypeName()} -> {dp.GetTypeName()}")
        for a in sp.GetAuthoredAttributes():
            out += _attr_losses(w, a, dp.GetAttribute(a.GetName()), rel)
        stack += list(sp.GetChildren())
    return out


def _binding_losses(where, sp, dp) -> list[str]:
    from pxr import UsdShade
    out = []
    for purpose in _PURPOSES:
        sm, _ = UsdShade.MaterialBindingAPI(sp).ComputeBoundMaterial(purpose)
        dm, _ = UsdShade.MaterialBindingAPI(dp).ComputeBoundMaterial(purpose)
        if not sm:
            continue
        if not dm:
            out.append(f"{where}: material binding ({purpose or 'allPurpose'}) lost: {sm.GetPath()}")
            continue
        out += _network_losses(where, sm.GetPrim(), dm.GetPrim())
    return out


def prim_losses(sp, dp, points_changed: bool = True) -> list[str]:
    """Losses of the output prim ``dp`` against the input prim ``sp``
    (``points_changed``: the output's points moved, normals are not compared)."""
    from pxr import UsdGeom
    where = f"{sp.GetPath()} -> {dp.GetPath()}"
    out = []
    sapi, dapi = UsdGeom.PrimvarsAPI(sp), UsdGeom.PrimvarsAPI(dp)
    for pv in sapi.FindPrimvarsWithInheritance():
        name = pv.GetPrimvarName()
        if is_geometric(pv.GetAttr().GetName(), points_changed):
            continue
        dpv = dapi.FindPrimvarWithInheritance(name)
        if not dpv:
            out.append(f"{where}: primvar {name} missing")
            continue
        for what, a, b in (("interpolation", pv.GetInterpolation(), dpv.GetInterpolation()),
                           ("elementSize", pv.GetElementSize(), dpv.GetElementSize()),
                           ("type", pv.GetTypeName(), dpv.GetTypeName()),
                           ("indexed", pv.IsIndexed(), dpv.IsIndexed())):
            if a != b:
                out.append(f"{where}: primvar {name} {what} {a} -> {b}")
        if not _same(pv.Get(), dpv.Get()) or not _same(pv.GetIndices(), dpv.GetIndices()):
            out.append(f"{where}: primvar {name} values differ")
    for a in sp.GetAuthoredAttributes():
        n = a.GetName()
        if is_geometric(n, points_changed) or n.startswith("primvars:"):
            continue
        out += _attr_losses(where, a, dp.GetAttribute(n))
    out += _binding_losses(where, sp, dp)
    for child in sp.GetChildren():
        if not child.IsA(UsdGeom.Subset):
            continue
        dc = dp.GetChild(child.GetName())
        if not dc or not dc.IsA(UsdGeom.Subset):
            out.append(f"{where}: GeomSubset {child.GetName()} missing")
            continue
        for a in child.GetAuthoredAttributes():
            out += _attr_losses(f"{where}/{child.GetName()}", a, dc.GetAttribute(a.GetName()))
        out += _binding_losses(f"{where}/{child.GetName()}", child, dc)
    for s in sp.GetAppliedSchemas():
        if not s.startswith("SkelBindingAPI") and s not in dp.GetAppliedSchemas():
            out.append(f"{where}: API schema {s} not applied")
    for k in _META_KEYS:
        if sp.HasAuthoredMetadata(k) and not _same(sp.GetMetadata(k), dp.GetMetadata(k)):
            out.append(f"{where}: metadata {k} differs")
    si, di = UsdGeom.Imageable(sp), UsdGeom.Imageable(dp)
    if si.ComputePurpose() != di.ComputePurpose():
        out.append(f"{where}: purpose {si.ComputePurpose()} -> {di.ComputePurpose()}")
    if si.ComputeVisibility() != di.ComputeVisibility():
        out.append(f"{where}: visibility {si.ComputeVisibility()} -> {di.ComputeVisibility()}")
    return out


def item_pairs(src_stage, dst_stage) -> dict:
    """{input item mesh path: output mesh path}: every input Mesh that is not
    bound to a skeleton, matched by name among the output's meshes."""
    from pxr import UsdGeom
    out_by_name = {}
    for p in dst_stage.Traverse():
        if p.IsA(UsdGeom.Mesh):
            out_by_name.setdefault(p.GetName(), p.GetPath())
    pairs = {}
    for p in src_stage.Traverse():
        if not p.IsA(UsdGeom.Mesh) or p.HasRelationship("skel:skeleton"):
            continue
        pairs[p.GetPath()] = out_by_name.get(p.GetName())
    return pairs


def check_carried(src_file, dst_file, pairs: dict | None = None, points_changed: bool = True) -> list[str]:
    """Everything ``dst_file`` lost of ``src_file``'s description.

    Parameters
    ----------
    src_file, dst_file : input and output USD files.
    pairs : {input prim path: output prim path}; default
        :func:`item_pairs` (the items, by name).
    points_changed : whether the output's points moved (normals not compared).

    Returns
    -------
    list of str, one line per lost or changed thing (empty: nothing lost).
    """
    from pxr import Usd
    src, dst = Usd.Stage.Open(str(src_file)), Usd.Stage.Open(str(dst_file))
    pairs = item_pairs(src, dst) if pairs is None else pairs
    out = []
    for s, d in pairs.items():
        sp = src.GetPrimAtPath(str(s))
        dp = dst.GetPrimAtPath(str(d)) if d is not None else None
        if not dp:
            out.append(f"{s}: no output prim")
            continue
        out += prim_losses(sp, dp, points_changed)
    return out
