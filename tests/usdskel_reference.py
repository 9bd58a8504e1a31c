"""Helpers that ask UsdSkel itself for skinned points (the ground truth)."""
from __future__ import annotations

import numpy as np


def author_animation(stage, skel_prim_path: str, local: np.ndarray, joints) -> None:
    """Author a SkelAnimation with (F, J, 4, 4) local transforms on ``stage``
    (in its session layer) and bind it to the skeleton."""
    from pxr import Gf, Sdf, UsdSkel, Vt

    from wearfit_usd.transforms import decompose, quat_from_matrix
    with_edit = stage.GetEditTarget()
    stage.SetEditTarget(stage.GetSessionLayer())
    anim_path = Sdf.Path(skel_prim_path).GetParentPath().AppendChild("TestAnim")
    anim = UsdSkel.Animation.Define(stage, anim_path)
    anim.CreateJointsAttr(Vt.TokenArray(list(joints)))
    t, r, s = decompose(local)
    q = quat_from_matrix(r)
    for f in range(local.shape[0]):
        anim.CreateTranslationsAttr().Set(Vt.Vec3fArray.FromNumpy(t[f].astype(np.float32)), f)
        anim.CreateRotationsAttr().Set(Vt.QuatfArray([Gf.Quatf(*map(float, x)) for x in q[f]]), f)
        anim.CreateScalesAttr().Set(Vt.Vec3hArray([Gf.Vec3h(*map(float, x)) for x in s[f]]), f)
    binding = UsdSkel.BindingAPI.Apply(stage.GetPrimAtPath(skel_prim_path))
    binding.CreateAnimationSourceRel().SetTargets([anim_path])
    stage.SetEditTarget(with_edit)


def usdskel_skinned_points(stage, mesh_path: str, time: float) -> np.ndarray:
    """World-space skinned points of ``mesh_path`` computed by UsdSkel."""
    from pxr import Usd, UsdGeom, UsdSkel
    cache = UsdSkel.Cache()
    pred = Usd.PrimDefaultPredicate
    for root in stage.Traverse():
        if not root.IsA(UsdSkel.Root):
            continue
        cache.Populate(UsdSkel.Root(root), pred)
        for b in cache.ComputeSkelBindings(UsdSkel.Root(root), pred):
            for target in b.GetSkinningTargets():
                if str(target.GetPrim().GetPath()) != mesh_path:
                    continue
                sq = cache.GetSkelQuery(b.GetSkeleton())
                xf = sq.ComputeSkinningTransforms(time)
                pts = UsdGeom.Mesh(target.GetPrim()).GetPointsAttr().Get(time)
                target.ComputeSkinnedPoints(xf, pts, time)
                skel_xf = UsdGeom.Xformable(b.GetSkeleton().GetPrim()).ComputeLocalToWorldTransform(time)
                p = np.array(pts, dtype=np.float64)
                m = np.array(skel_xf)
                return p @ m[:3, :3] + m[3, :3]
    raise KeyError(mesh_path)
