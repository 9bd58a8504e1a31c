"""Carry the non-geometric description of prims from input stages to an
output stage: everything an asset says about a mesh besides where its points
are.

The toolkit changes point positions only (items keep their topology; the
target body keeps its points), so a written mesh can take over its input
prim's materials (``material:binding``, with the bound ``Material`` networks
copied under ``/Root/Materials``), ``GeomSubset`` children (``materialBind``
families with their own bindings), every primvar (``st`` and other UV sets,
``displayColor``/``displayOpacity``, custom ones, with interpolation,
elementSize and indices), ``subdivisionScheme``, ``purpose``, custom
attributes, applied API schemas and prim metadata (``kind``, ``customData``,
``assetInfo``, ...). Inherited opinions are resolved: a binding or a
constant primvar on an ancestor is authored on the written mesh.

Not carried (the writer authors them for the new points): ``points``,
``extent``, ``velocities``, ``accelerations``, transforms (the writers bake
world space into the points), skinning (``skel:*``, re-authored against the
written skeleton), and ``normals`` when the points moved (recomputed).

Two ways (:class:`CarryPlan`): copy (default; the output stands alone), or
with ``reference_inputs`` the written prims *reference* their input prims
(``references = @input@</path>``), so later edits of the input's materials,
UVs or attributes flow through, and the output layer authors only what the
toolkit computes (points, extent, normals, skinning, time samples) plus the
bindings re-targeted to the output's material paths.

A mesh whose faces were dropped (``--delete-hidden-body``) passes the kept
polygons (``poly_keep``): its vertex, face-varying and uniform data and its
subsets are re-indexed (such a prim is always copied: its input's arrays no
longer match).

:func:`check_carried` lists what an output lost against its input (the
test of the feature, also usable on any output).

``pxr`` is imported when a function runs, like the other writers.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

#: attributes the writer authors from the computed geometry (never carried)
GEOMETRY_ATTRS = {"points", "extent", "velocities", "accelerations", "xformOpOrder"}
#: depend on the points: carried only when the points did not move
POINT_DEPENDENT = {"normals", "primvars:normals", "primvars:normals:indices"}
#: prim metadata that is composition or bookkeeping, not description
_SKIP_PRIM_META = {"specifier", "typeName", "references", "payload", "inheritPaths", "specializes",
                   "variantSetNames", "variantSelection", "variantSetChildren", "clips", "clipSets",
                   "primOrder", "propertyOrder", "apiSchemas", "sdrMetadata", "prefixSubstitutions",
                   "suffixSubstitutions", "instanceable", "active"}
_SKIP_PROP_META = {"typeName", "custom", "variability", "default", "timeSamples", "connectionPaths",
                   "targetPaths", "spline"}
#: family name of the hidden-body face subsets
HIDDEN_FAMILY = "wearfit:hidden"
#: the subset of body faces covered by any item
HIDDEN_SUBSET = "hidden_under_items"
#: where copied materials go in the output
MATERIALS_SCOPE = "Materials"


def is_geometric(name: str, points_changed: bool = True) -> bool:
    """Whether an attribute ``name`` belongs to the computed geometry (the
    writer's job) rather than to the asset's description."""
    if name in GEOMETRY_ATTRS or name.startswith("xformOp:"):
        return True
    if name.startswith("skel:") or name.startswith("primvars:skel:"):
        return True
    return points_changed and name in POINT_DEPENDENT


def is_usd_file(path) -> bool:
    """Whether ``path`` is a USD layer to carry from (a glTF, .obj or .ply
    input has no USD prims: nothing to carry)."""
    return Path(str(path)).suffix.lower() in (".usd", ".usda", ".usdc", ".usdz")


@dataclass
class CarrySource:
    """One written mesh's input: ``file`` and ``prim`` path in it.

    points_changed: the toolkit moved the points (normals are recomputed,
    not carried). poly_keep: (P,) bool over the input's polygons when faces
    were dropped (data re-indexed to the kept ones), else None.
    """
    file: str
    prim: str
    points_changed: bool = True
    poly_keep: np.ndarray | None = None


@dataclass
class CarryPlan:
    """What :func:`carry` copies: the body's and each item's input prim
    (items by their output name) and whether to reference the inputs."""
    body: CarrySource | None = None
    items: dict = field(default_factory=dict)
    reference_inputs: bool = False
    body_subsets: dict = field(default_factory=dict)   # {name: polygon indices} on the body

    @classmethod
    def for_dress(cls, reference, target, items, reference_inputs: bool = False,
                  body_poly_keep=None, body_from_reference: bool = False) -> CarryPlan:
        """The plan of a dress/animate output: items from ``reference`` (a
        Character; ``items`` the written Mesh list, same names), the body from
        ``target`` (unchanged points), or with ``body_from_reference`` from
        the reference (a fitted body: moved points, as ``wearfit fit``)."""
        src = reference if body_from_reference else target
        body = None
        if src is not None and src.body.path and is_usd_file(src.source):
            body = CarrySource(str(src.source), src.body.path, points_changed=body_from_reference,
                               poly_keep=body_poly_keep)
        by_name = {m.name: m for m in reference.items} if reference is not None else {}
        its = {}
        for m in items:
            srcm = by_name.get(m.name)
            path = (srcm.path if srcm is not None else m.path)
            if path and is_usd_file(reference.source):
                its[m.name] = CarrySource(str(reference.source), path, points_changed=True)
        return cls(body=body, items=its, reference_inputs=reference_inputs)

    def with_hidden(self, subsets: dict, poly_keep=None) -> CarryPlan:
        """This plan with the body's hidden subsets, or (``poly_keep``, the
        kept polygons) with its hidden polygons dropped."""
        body = self.body
        if body is not None and poly_keep is not None:
            body = replace(body, poly_keep=np.asarray(poly_keep, dtype=bool))
        return replace(self, body=body, body_subsets=dict(subsets))


class _Carrier:
    """One output stage's carrying: opened inputs, copied materials."""

    def __init__(self, stage, out_file, reference_inputs: bool):
        from pxr import Sdf
        self.stage = stage
        self.out_dir = Path(out_file).resolve().parent
        self.reference = reference_inputs
        self.inputs = {}
        self.copied = {}          # (file, source path) -> output path
        self.names = set()
        root = stage.GetDefaultPrim().GetPath() if stage.GetDefaultPrim() else Sdf.Path("/Root")
        self.mat_root = root.AppendChild(MATERIALS_SCOPE)

    def open(self, file):
        from pxr import Usd
        key = str(Path(file).resolve())
        if key not in self.inputs:
            self.inputs[key] = Usd.Stage.Open(key)
        return self.inputs[key]

    def asset(self, file) -> str:
        """Asset path of an input as seen from the output's folder."""
        p = Path(file).resolve()
        try:
            rel = os.path.relpath(p, self.out_dir)
        except ValueError:  # another drive
            return str(p)
        return rel if rel.startswith(".") else f"./{rel}"

    # ------------------------------------------------------------------
    def material(self, file, src_prim):
        """Output path of the copy (or reference) of a material-like prim
        (Material, NodeGraph, Shader...) of ``file``; copied once."""
        from pxr import UsdGeom
        key = (str(Path(file).resolve()), str(src_prim.GetPath()))
        if key in self.copied:
            return self.copied[key]
        if not self.stage.GetPrimAtPath(self.mat_root):
            UsdGeom.Scope.Define(self.stage, self.mat_root)
        name = src_prim.GetName()
        base, i = name, 1
        while name in self.names:
            name = f"{base}_{i}"
            i += 1
        self.names.add(name)
        dst = self.mat_root.AppendChild(name)
        self.copied[key] = dst
        src_root = src_prim.GetPath()
        if self.reference:
            prim = self.stage.DefinePrim(dst, src_prim.GetTypeName())
            prim.GetReferences().AddReference(self.asset(file), src_root)
            # connections leaving the network: re-target them here
            for p in _descendants(src_prim):
                for a in p.GetAttributes():
                    cons = a.GetConnections()
                    outside = [c for c in cons if not c.HasPrefix(src_root)]
                    if outside:
                        dp = self.stage.OverridePrim(p.GetPath().ReplacePrefix(src_root, dst))
                        da = dp.CreateAttribute(a.GetName(), a.GetTypeName(), a.IsCustom())
                        da.SetConnections([self.remap(file, c, src_root, dst) for c in cons])
            return dst

        def copy_tree(sp, dpath):
            dp = self.stage.DefinePrim(dpath, sp.GetTypeName())
            self.copy_prim(file, sp, dp, points_changed=False, remap_root=(src_root, dst), skip_geometry=False)
            for c in sp.GetChildren():
                copy_tree(c, dpath.AppendChild(c.GetName()))
        copy_tree(src_prim, dst)
        return dst

    def remap(self, file, path, src_root=None, dst_root=None):
        """A target or connection path of ``file`` in the output's namespace
        (None: not carried)."""
        if src_root is not None and path.HasPrefix(src_root):
            return path.ReplacePrefix(src_root, dst_root)
        st = self.open(file)
        prim_path = path.GetPrimPath()
        prim = st.GetPrimAtPath(prim_path)
        if not prim:
            return None
        from pxr import UsdShade
        owner = prim
        # the outermost material-like ancestor is the unit that is copied
        p = prim
        while p and not p.IsPseudoRoot():
            if p.IsA(UsdShade.Material) or p.IsA(UsdShade.NodeGraph):
                owner = p
            p = p.GetParent()
        if not (owner.IsA(UsdShade.Material) or owner.IsA(UsdShade.NodeGraph) or owner.IsA(UsdShade.Shader)):
            return None
        dst = self.material(file, owner)
        return path.ReplacePrefix(owner.GetPath(), dst)

    # ------------------------------------------------------------------
    def copy_prim(self, file, src, dst, points_changed=True, remap_root=None, skip_geometry=True,
                  only_missing=False, poly_keep=None):
        """Author ``src``'s description on ``dst``: metadata, applied schemas,
        attributes (values, samples, connections, metadata), relationships."""
        from pxr import Usd
        rr = remap_root or (None, None)
        meta = src.GetAllAuthoredMetadata()
        for k, v in meta.items():
            if k in _SKIP_PRIM_META:
                continue
            try:
                dst.SetMetadata(k, v)
            except Exception:
                pass
        for schema in src.GetAppliedSchemas():
            if schema.startswith("SkelBindingAPI"):
                continue
            if schema not in dst.GetAppliedSchemas():
                dst.AddAppliedSchema(schema)
        keep = None if poly_keep is None else _KeepMaps(src, poly_keep)
        for prop in src.GetAuthoredProperties():
            name = prop.GetName()
            if skip_geometry and is_geometric(name, points_changed):
                continue
            if keep is not None and name in ("faceVertexCounts", "faceVertexIndices", "holeIndices",
                                             "cornerIndices", "cornerSharpnesses", "creaseIndices",
                                             "creaseLengths", "creaseSharpnesses"):
                continue  # the writer authors the reduced topology
            if only_missing and dst.GetProperty(name) and dst.GetProperty(name).IsAuthored():
                continue
            if isinstance(prop, Usd.Attribute):
                da = dst.GetAttribute(name)
                if not da:
                    da = dst.CreateAttribute(name, prop.GetTypeName(), prop.IsCustom(), prop.GetVariability())
                for k, v in prop.GetAllAuthoredMetadata().items():
                    if k not in _SKIP_PROP_META:
                        try:
                            da.SetMetadata(k, v)
                        except Exception:
                            pass
                v = prop.Get(Usd.TimeCode.Default())
                if v is not None:
                    da.Set(keep.value(prop, v) if keep is not None else v)
                for t in prop.GetTimeSamples():
                    sv = prop.Get(t)
                    da.Set(keep.value(prop, sv) if keep is not None else sv, t)
                cons = prop.GetConnections()
                if cons:
                    out = [self.remap(file, c, *rr) for c in cons]
                    da.SetConnections([c for c in out if c is not None])
            else:
                targets = prop.GetTargets()
                out = [self.remap(file, t, *rr) for t in targets]
                out = [t for t in out if t is not None]
                if targets and not out:
                    continue  # nothing it named is in the output (e.g. a proxyPrim)
                r = dst.GetRelationship(name) or dst.CreateRelationship(name, prop.IsCustom())
                r.SetTargets(out)

    def carry_mesh(self, src_file, src_path, dst_path, points_changed=True, poly_keep=None):
        """Carry one mesh prim (and its GeomSubset children) onto the
        output's prim at ``dst_path``. Returns the carried property names."""
        from pxr import UsdGeom, UsdShade
        st = self.open(src_file)
        src = st.GetPrimAtPath(src_path)
        if not src:
            return []
        dst = self.stage.GetPrimAtPath(dst_path)
        by_ref = self.reference and poly_keep is None
        if by_ref:
            dst.GetReferences().AddReference(self.asset(src_file), src.GetPath())
            self._thin_local(src, dst, points_changed)
            # bindings point outside the referenced prim: re-target them here
            for p in [src] + [c for c in src.GetChildren()]:
                for rel in p.GetRelationships():
                    tg = rel.GetTargets()
                    out = [self.remap(src_file, t) for t in tg]
                    out = [t for t in out if t is not None]
                    if out:
                        dp = dst if p == src else self.stage.OverridePrim(dst_path.AppendChild(p.GetName()))
                        (dp.GetRelationship(rel.GetName()) or dp.CreateRelationship(rel.GetName(), rel.IsCustom())
                         ).SetTargets(out)
        else:
            self.copy_prim(src_file, src, dst, points_changed, poly_keep=poly_keep)
            for child in src.GetChildren():
                if not child.IsA(UsdGeom.Subset):
                    continue
                sub = UsdGeom.Subset.Define(self.stage, dst_path.AppendChild(child.GetName()))
                self.copy_prim(src_file, child, sub.GetPrim(), False)
                if poly_keep is not None:
                    _reindex_subset(sub, child, poly_keep)
        # inherited opinions resolved onto the written mesh
        if not UsdShade.MaterialBindingAPI(src).GetDirectBindingRel():
            mat, _ = UsdShade.MaterialBindingAPI(src).ComputeBoundMaterial()
            if mat:
                m = self.remap(src_file, mat.GetPath())
                if m is not None:
                    UsdShade.MaterialBindingAPI.Apply(dst).Bind(UsdShade.Material(self.stage.GetPrimAtPath(m)))
        api = UsdGeom.PrimvarsAPI(dst)
        for pv in UsdGeom.PrimvarsAPI(src).FindPrimvarsWithInheritance():
            if pv.GetAttr().GetPrim() == src or dst.GetAttribute(pv.GetAttr().GetName()).IsAuthored():
                continue  # its own primvars were carried above (a schema's builtin is no opinion)
            v = pv.Get()
            if v is None:
                continue
            api.CreatePrimvar(pv.GetPrimvarName(), pv.GetTypeName(), UsdGeom.Tokens.constant).Set(v)
        purpose = UsdGeom.Imageable(src).ComputePurpose()
        if purpose != UsdGeom.Tokens.default_ and not UsdGeom.Imageable(dst).GetPurposeAttr().HasAuthoredValue():
            UsdGeom.Imageable(dst).CreatePurposeAttr(purpose)
        return [p.GetName() for p in src.GetAuthoredProperties()]

    def _thin_local(self, src, dst, points_changed):
        """Reference mode: drop the writer's local opinions the input holds
        (the input's flow through), keep the geometry, block the input's
        transforms and skinning (world-space points, the output's skeleton)."""
        from pxr import UsdGeom
        spec = self.stage.GetEditTarget().GetLayer().GetPrimAtPath(dst.GetPath())
        src_props = {p.GetName() for p in src.GetAuthoredProperties()}
        for name in list(spec.properties.keys()) if spec else []:
            if name in src_props and not is_geometric(name, points_changed):
                spec.RemoveProperty(spec.properties[name])
        UsdGeom.Xformable(dst).CreateXformOpOrderAttr().Set([])
        for name in src_props:
            # the input's transforms and skinning must not apply (points are
            # in world space, skinned against the output's skeleton); the
            # geometry the writer authors (maybe in value clips) is left alone
            local = spec is not None and name in spec.properties
            if not local and (name.startswith("xformOp:") or name.startswith("skel:")
                              or name.startswith("primvars:skel:") or name in ("velocities", "accelerations")):
                a = dst.GetAttribute(name)
                if a:
                    a.Block()


def _descendants(prim):
    """``prim`` and every prim under it."""
    out = [prim]
    for c in prim.GetChildren():
        out += _descendants(c)
    return out


class _KeepMaps:
    """Index maps of a mesh whose polygons were reduced to ``poly_keep``:
    per interpolation, the kept elements of the input's arrays."""

    def __init__(self, src_prim, poly_keep):
        from pxr import UsdGeom
        m = UsdGeom.Mesh(src_prim)
        counts = np.asarray(m.GetFaceVertexCountsAttr().Get(), dtype=np.int64)
        idx = np.asarray(m.GetFaceVertexIndicesAttr().Get(), dtype=np.int64)
        n = len(m.GetPointsAttr().Get())
        keep_poly = np.asarray(poly_keep, dtype=bool)
        corner_keep = np.repeat(keep_poly, counts)
        vert = np.zeros(n, dtype=bool)
        vert[idx[corner_keep]] = True
        self.sel = {"vertex": vert, "varying": vert, "faceVarying": corner_keep, "uniform": keep_poly}
        self.n = {"vertex": n, "varying": n, "faceVarying": len(idx), "uniform": len(counts)}

    def value(self, attr, v):
        """``v`` of ``attr`` (a primvar, its indices, or normals) reduced to
        the kept elements; other values unchanged."""
        from pxr import UsdGeom
        name = attr.GetName()
        base = name[:-len(":indices")] if name.endswith(":indices") else name
        prim = attr.GetPrim()
        if base == "normals":
            interp = UsdGeom.Mesh(prim).GetNormalsInterpolation()
            indexed = False
        elif base.startswith("primvars:"):
            pv = UsdGeom.Primvar(prim.GetAttribute(base))
            interp = pv.GetInterpolation()
            indexed = pv.IsIndexed()
        else:
            return v
        if interp not in self.sel:
            return v
        if indexed and not name.endswith(":indices"):
            return v  # the values are shared; the indices are reduced
        esize = 1
        if base.startswith("primvars:"):
            esize = max(int(UsdGeom.Primvar(prim.GetAttribute(base)).GetElementSize()), 1)
        if len(v) != self.n[interp] * esize:
            return v
        arr = np.asarray(v)
        sel = np.repeat(self.sel[interp], esize)
        return type(v).FromNumpy(np.ascontiguousarray(arr[sel])) if hasattr(type(v), "FromNumpy") else \
            type(v)([x for x, k in zip(v, sel) if k])


def _reindex_subset(sub, src_subset, poly_keep):
    """A face subset's indices in the reduced mesh (dropped faces left out)."""
    from pxr import Vt
    keep = np.asarray(poly_keep, dtype=bool)
    new_index = np.cumsum(keep) - 1
    idx = np.asarray(src_subset.GetAttribute("indices").Get() or [], dtype=np.int64)
    idx = idx[(idx >= 0) & (idx < len(keep))]
    idx = new_index[idx[keep[idx]]]
    sub.GetIndicesAttr().Set(Vt.IntArray.FromNumpy(idx.astype(np.int32)))


def carry(plan: CarryPlan | None, stage, out_file, body_path, item_paths: dict) -> None:
    """Carry ``plan``'s inputs onto a stage being written.

    Parameters
    ----------
    plan : what to carry (None: nothing).
    stage : the output ``Usd.Stage`` (its layer is saved by the caller).
    out_file : the output's final path (relative asset paths of references).
    body_path : ``Sdf.Path`` of the written body mesh, or None.
    item_paths : [(item name, ``Sdf.Path``)] of the written item meshes
        (an item may be written twice: point cache and skinned), or a dict.
    """
    if plan is None:
        return
    c = _Carrier(stage, out_file, plan.reference_inputs)
    if plan.body is not None and body_path is not None:
        b = plan.body
        c.carry_mesh(b.file, b.prim, body_path, b.points_changed, b.poly_keep)
    pairs = item_paths.items() if isinstance(item_paths, dict) else item_paths
    for name, dst in pairs:
        src = plan.items.get(name)
        if src is not None:
            c.carry_mesh(src.file, src.prim, dst, src.points_changed, src.poly_keep)
    if body_path is not None and plan.body_subsets:
        author_face_subsets(stage, body_path, plan.body_subsets)


def author_face_subsets(stage, mesh_path, subsets: dict) -> None:
    """Author ``{name: (F,) polygon indices}`` as face GeomSubsets of the
    mesh at ``mesh_path`` (family ``wearfit:hidden``, non-overlapping not
    claimed: an item's subset is part of the union's)."""
    from pxr import UsdGeom, Vt
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(mesh_path))
    for name, idx in subsets.items():
        sub = UsdGeom.Subset.CreateGeomSubset(
            mesh, name, UsdGeom.Tokens.face,
            Vt.IntArray.FromNumpy(np.ascontiguousarray(np.asarray(idx, dtype=np.int32))),
            HIDDEN_FAMILY, UsdGeom.Tokens.unrestricted)
        sub.GetPrim().SetCustomDataByKey("wearfit:doc", "body faces covered by items (not drawn; "
                                         "--delete-hidden-body drops them)")
