"""USD authoring shared by the writers: stage layout, skeleton, meshes.

:class:`StageLayout` sets a new stage's up axis and units and names the
prims (``/Root/Character/{Skeleton,Body,Animation}``, ``/Root/Items``);
the ``author_*`` functions define the skeleton, the skinned body and static
or skinned items from internal-space :mod:`wearfit_usd.model` data;
:func:`vt_points` / :func:`vt_extent` convert (N, 3) arrays to ``Vt``
arrays. Used by :func:`wearfit_usd.io.usd.write_character` and
:class:`wearfit_usd.io.usd_shot.ShotWriter`. ``pxr`` is imported when a
function runs (as in :mod:`.usd`), not when this module is.
"""
from __future__ import annotations

import re

import numpy as np

from ..geometry.closest import vertex_normals
from ..model import Mesh, Skeleton
from ..transforms import invert, stage_to_internal, transform_points
from ..types import Points


def vt_points(points: Points):
    """(N, 3) array -> ``Vt.Vec3fArray`` (float32)."""
    from pxr import Vt
    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, dtype=np.float32))


def vt_extent(points: Points):
    """``Vt.Vec3fArray`` [min, max] corners of (N, 3) points (float32)."""
    from pxr import Vt
    # column by column: numpy's axis-0 reduction of an (M, 3) array is ~8x slower
    ext = np.array([[points[:, i].min() for i in range(3)], [points[:, i].max() for i in range(3)]],
                   dtype=np.float32)
    return Vt.Vec3fArray.FromNumpy(ext)


class StageLayout:
    """Prim paths and stage metadata shared by the writers."""

    def __init__(self, stage, up_axis, meters_per_unit, root="Root"):
        from pxr import Sdf, UsdGeom
        self.stage = stage
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if str(up_axis).upper() == "Z" else UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
        self.root = Sdf.Path(f"/{root}")
        root_prim = UsdGeom.Xform.Define(stage, self.root).GetPrim()
        stage.SetDefaultPrim(root_prim)
        self.skel_root = self.root.AppendChild("Character")
        self.skel_path = self.skel_root.AppendChild("Skeleton")
        self.body_path = self.skel_root.AppendChild("Body")
        self.anim_path = self.skel_root.AppendChild("Animation")
        self.items_path = self.root.AppendChild("Items")
        self.to_internal = stage_to_internal(up_axis, meters_per_unit)
        self.from_internal = invert(self.to_internal)


def prim_name(name: str) -> str:
    """``name`` made a valid USD prim name (other characters -> ``_``, no
    leading digit)."""
    s = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return s if s and not s[0].isdigit() else f"_{s}"


def author_mesh_topology(usd_mesh, mesh: Mesh):
    """Author ``mesh``'s polygons, orientation, double-sidedness, primvars
    and display colour on ``usd_mesh`` (a ``UsdGeom.Mesh``); no points."""
    from pxr import Sdf, UsdGeom, Vt
    usd_mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(mesh.face_vertex_counts.astype(np.int32)))
    usd_mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(mesh.face_vertex_indices.astype(np.int32)))
    usd_mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    usd_mesh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded if mesh.left_handed else UsdGeom.Tokens.rightHanded)
    if mesh.double_sided:
        usd_mesh.CreateDoubleSidedAttr(True)
    api = UsdGeom.PrimvarsAPI(usd_mesh.GetPrim())
    for pv in mesh.primvars:
        tn = Sdf.ValueTypeNames.Find(pv.type_name)
        if not tn:
            continue
        p = api.CreatePrimvar(pv.name, tn, pv.interpolation, pv.element_size)
        try:
            p.Set(tn.type.pythonClass(pv.values.tolist()) if pv.values.dtype == object else pv.values)
        except Exception:
            try:
                p.Set(tn.type.pythonClass.FromNumpy(pv.values))
            except Exception:
                continue
        if pv.indices is not None:
            p.SetIndices(Vt.IntArray.FromNumpy(pv.indices.astype(np.int32)))
    if mesh.display_color is not None and not any(pv.name == "displayColor" for pv in mesh.primvars):
        usd_mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(
            [tuple(float(c) for c in mesh.display_color)])


def author_skeleton(layout: StageLayout, skeleton: Skeleton):
    """Skeleton prim at identity under the SkelRoot; transforms re-expressed
    so the stage's world pose equals the internal one."""
    from pxr import UsdSkel, Vt
    out = Skeleton(skeleton.joint_names, skeleton.joint_paths, skeleton.parents,
                   skeleton.bind_world, skeleton.rest_local, layout.to_internal)
    bind_skel = skeleton.bind_world @ layout.from_internal
    rest_world = skeleton.rest_world()
    rest_local = out.local_from_world(rest_world)
    skel = UsdSkel.Skeleton.Define(layout.stage, layout.skel_path)
    skel.CreateJointsAttr(Vt.TokenArray(skeleton.joint_paths))
    skel.CreateJointNamesAttr(Vt.TokenArray(skeleton.joint_names))
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray.FromNumpy(np.ascontiguousarray(bind_skel)))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray.FromNumpy(np.ascontiguousarray(rest_local)))
    return skel, out


def author_body(layout: StageLayout, body: Mesh, skeleton: Skeleton | None):
    """Define the body Mesh (``layout.body_path``) from internal-space
    ``body``, skinned to the layout's skeleton when ``skeleton`` is given
    and the body has influences. A body merged from parts
    (:func:`~wearfit_usd.model.merge_meshes`) is written as one Mesh per part
    under a ``Body`` Xform. Returns the (first) ``UsdGeom.Mesh``."""
    from pxr import UsdGeom
    if len(body.parts) > 1:
        # a body read as several skinned meshes: written apart again, one
        # Mesh per part under a Body Xform (names kept, made unique)
        UsdGeom.Xform.Define(layout.stage, layout.body_path)
        names: set = set()
        out = []
        for part in body.split_parts():
            name = prim_name(part.name)
            while name in names:
                name += "_"
            names.add(name)
            out.append(_author_body_mesh(layout, layout.body_path.AppendChild(name), part, skeleton))
        return out[0]
    return _author_body_mesh(layout, layout.body_path, body, skeleton)


def _author_body_mesh(layout: StageLayout, prim_path, body: Mesh, skeleton: Skeleton | None):
    from pxr import UsdGeom
    pts = transform_points(body.points, layout.from_internal)
    m = UsdGeom.Mesh.Define(layout.stage, prim_path)
    m.CreatePointsAttr(vt_points(pts))
    m.CreateExtentAttr(vt_extent(pts))
    author_mesh_topology(m, body)
    if skeleton is not None and body.joint_indices is not None:
        author_skin_binding(layout, m, body)
    return m


def author_static_item(layout: StageLayout, item: Mesh, skeleton: Skeleton | None):
    """Define an item Mesh from internal-space ``item``: a plain mesh under
    ``/Root/Items``, or skinned inside the SkelRoot when ``skeleton`` is given
    and the item has influences. Returns the ``UsdGeom.Mesh``."""
    from pxr import UsdGeom
    if skeleton is not None and item.joint_indices is not None:
        ipath = layout.skel_root.AppendChild(prim_name(item.name))
    else:
        ipath = layout.items_path.AppendChild(prim_name(item.name))
    pts = transform_points(item.points, layout.from_internal)
    m = UsdGeom.Mesh.Define(layout.stage, ipath)
    m.CreatePointsAttr(vt_points(pts))
    m.CreateExtentAttr(vt_extent(pts))
    author_mesh_topology(m, item)
    if item.normals_interpolation is not None:
        m.CreateNormalsAttr(vt_points(vertex_normals(pts, item.faces) * (-1 if item.left_handed else 1)))
        m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    if skeleton is not None and item.joint_indices is not None:
        author_skin_binding(layout, m, item)
    return m


def author_skin_binding(layout: StageLayout, usd_mesh, mesh: Mesh) -> None:
    """Bind ``usd_mesh`` to the layout's skeleton with ``mesh``'s (N, K)
    joint indices and weights (vertex primvars, identity geomBindTransform:
    the points are already in bind pose)."""
    from pxr import Gf, UsdSkel, Vt
    api = UsdSkel.BindingAPI.Apply(usd_mesh.GetPrim())
    api.CreateSkeletonRel().SetTargets([layout.skel_path])
    k = mesh.joint_indices.shape[1]
    api.CreateJointIndicesPrimvar(False, k).Set(
        Vt.IntArray.FromNumpy(mesh.joint_indices.astype(np.int32).ravel()))
    api.CreateJointWeightsPrimvar(False, k).Set(
        Vt.FloatArray.FromNumpy(mesh.joint_weights.astype(np.float32).ravel()))
    api.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
