"""Reading rigged stages, writing static and animated stages (round trips,
UsdSkel agreement, validation, value clips, clear errors, atomic output)."""
from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import USD_DIR
from tests.usdskel_reference import usdskel_skinned_points
from wearfit_usd.errors import GeometryError, InputError, USDInputError
from wearfit_usd.io.usd import read_character, triangulate, write_character
from wearfit_usd.io.usd_shot import ShotWriter
from wearfit_usd.io.usd_validate import validate_stage, validator_count
from wearfit_usd.motion.skinning import skin_mesh
from wearfit_usd.transforms import make_matrix, matrix_from_quat, transform_points


def test_triangulate_quads_and_ngons():
    counts = np.array([4, 3, 5])
    idx = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11])
    faces, t2p = triangulate(counts, idx)
    assert faces.shape == (2 + 1 + 3, 3)
    np.testing.assert_array_equal(t2p, [0, 0, 1, 2, 2, 2])
    np.testing.assert_array_equal(faces[0], [0, 1, 2])
    np.testing.assert_array_equal(faces[-1], [7, 10, 11])
    lf, _ = triangulate(counts, idx, left_handed=True)
    np.testing.assert_array_equal(lf[0], [2, 1, 0])


def test_read_reference_male(ref_male):
    c = ref_male
    assert c.up_axis == "Z" and c.meters_per_unit == 1.0
    assert c.body.n_points == 13380 and len(c.body.face_vertex_counts) == 13378
    assert c.skeleton.n_joints == 53
    names = sorted(m.name for m in c.items)
    assert names == sorted(["male_casualsuit01", "shoes01", "fedora01", "short02", "eyebrow001"])
    np.testing.assert_allclose(c.body.joint_weights.sum(axis=1), 1.0, atol=1e-6)
    # Y up internally: the body stands along +Y, about 1.73 m tall
    ext = c.body.points.max(0) - c.body.points.min(0)
    assert np.argmax(ext) == 1 and 1.65 < ext[1] < 1.8
    # faces +Z: the nose (max z) is near the top of the body
    nose = c.body.points[np.argmax(c.body.points[:, 2])]
    assert nose[1] > c.body.points[:, 1].min() + 0.5 * ext[1]


def test_y_up_and_z_up_bodies_agree():
    zup = read_character(USD_DIR / "body_female_heavy.usdc")
    yup = read_character(USD_DIR / "body_female_uncommon_yup.usdc")
    for c in (zup, yup):
        ext = c.body.points.max(0) - c.body.points.min(0)
        assert np.argmax(ext) == 1  # both stand along internal +Y
    assert yup.up_axis == "Y"


def test_write_character_round_trip(tmp_path, ref_male):
    out = tmp_path / "copy.usdc"
    write_character(out, ref_male)
    back = read_character(out)
    np.testing.assert_allclose(back.body.points, ref_male.body.points, atol=1e-6)
    np.testing.assert_array_equal(back.body.face_vertex_counts, ref_male.body.face_vertex_counts)
    np.testing.assert_array_equal(back.body.face_vertex_indices, ref_male.body.face_vertex_indices)
    np.testing.assert_allclose(back.skeleton.bind_world, ref_male.skeleton.bind_world, atol=1e-6)
    np.testing.assert_allclose(back.skeleton.rest_world(), ref_male.skeleton.rest_world(), atol=1e-5)
    for a in ref_male.items:
        b = back.item(a.name)
        np.testing.assert_allclose(b.points, a.points, atol=1e-6)
        np.testing.assert_array_equal(b.face_vertex_indices, a.face_vertex_indices)
    assert validate_stage(out) == []


def test_write_in_other_up_axis_and_units(tmp_path, ref_female):
    out = tmp_path / "yup_cm.usda"
    write_character(out, ref_female, up_axis="Y", meters_per_unit=0.01)
    back = read_character(out)
    assert back.up_axis == "Y" and back.meters_per_unit == pytest.approx(0.01)
    np.testing.assert_allclose(back.body.points, ref_female.body.points, atol=1e-5)
    # the skinning still matches after the change of space
    local = back.skeleton.rest_local.copy()
    local[5] = make_matrix(rotation=matrix_from_quat(np.array([0.9, 0.3, 0.1, 0.2]))) @ local[5]
    a = skin_mesh(back.body, back.skeleton, back.skeleton.world_from_local(local))
    assert np.abs(a - back.body.points).max() > 0.01


def _anim(skel, n, rng):
    local = np.repeat(skel.rest_local[None], n, axis=0)
    for f in range(1, n):
        q = np.concatenate([np.ones((skel.n_joints, 1)), rng.normal(scale=0.15 * f, size=(skel.n_joints, 3))], 1)
        local[f] = make_matrix(rotation=matrix_from_quat(q)) @ skel.rest_local
    return local


@pytest.mark.parametrize("clip_frames", [None, 2])
def test_shot_writer_body_matches_usdskel_and_items_sampled(tmp_path, ref_male, clip_frames):
    rng = np.random.default_rng(3)
    skel = ref_male.skeleton
    n = 5
    local = _anim(skel, n, rng)
    world = skel.world_from_local(local)
    ours = skin_mesh(ref_male.body, skel, world)
    items = ref_male.items[:2]
    out = tmp_path / "shot.usda"
    with ShotWriter(out, ref_male, items, fps=30, n_frames=n, clip_frames=clip_frames,
                    velocities=True) as w:
        w.write_animation(local)
        for f in range(n):
            w.write_frame(f, [m.points + [0, 0.01 * f, 0] for m in items])
    assert out.exists()
    from pxr import Usd, UsdGeom
    stage = Usd.Stage.Open(str(out))
    assert stage.GetTimeCodesPerSecond() == 30 and stage.GetEndTimeCode() == n - 1
    assert validate_stage(stage) == []
    back = read_character(out)
    for f in (0, 2, 4):
        ref = transform_points(usdskel_skinned_points(stage, "/Root/Character/Body", f), back.to_internal)
        assert np.abs(ref - ours[f]).max() < 1e-4
    for m in items:
        prim = UsdGeom.Mesh(stage.GetPrimAtPath(f"/Root/Items/{m.name}"))
        p3 = transform_points(np.array(prim.GetPointsAttr().Get(3)), back.to_internal)
        np.testing.assert_allclose(p3, m.points + [0, 0.03, 0], atol=1e-5)
        ext = np.array(prim.GetExtentAttr().Get(3))
        np.testing.assert_allclose(ext[1], np.array(prim.GetPointsAttr().Get(3)).max(0), atol=1e-6)
        vel = np.array(prim.GetVelocitiesAttr().Get(2))
        assert np.abs(vel).max() > 0
    if clip_frames:
        assert (tmp_path / "shot.clips").is_dir() and len(list((tmp_path / "shot.clips").iterdir())) == 3


def test_shot_writer_leaves_nothing_on_failure(tmp_path, ref_male):
    out = tmp_path / "bad.usdc"
    with pytest.raises(RuntimeError):
        with ShotWriter(out, ref_male, ref_male.items[:1], fps=24, n_frames=3, clip_frames=2) as w:
            w.write_frame(0, [ref_male.items[0].points])
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_validator_count():
    assert validator_count() >= 20


# ---------------------------------------------------------------- bad input

def _edit_copy(tmp_path, edit):
    from pxr import Usd
    src = Usd.Stage.Open(str(USD_DIR / "ref_male.usda"))
    layer = src.Flatten()
    path = tmp_path / "edited.usda"
    layer.Export(str(path))
    st = Usd.Stage.Open(str(path))
    edit(st)
    st.GetRootLayer().Save()
    return path


def test_missing_file():
    with pytest.raises(InputError, match="file not found"):
        read_character("/nonexistent/body.usda")


def test_no_skinned_mesh(tmp_path):
    from pxr import UsdSkel
    def edit(st):
        UsdSkel.BindingAPI(st.GetPrimAtPath("/root/Skeleton/Body/Body")).GetSkeletonRel().ClearTargets(True)
    with pytest.raises(USDInputError, match="no skinned mesh"):
        read_character(_edit_copy(tmp_path, edit))


def test_weights_length_mismatch(tmp_path):
    from pxr import UsdSkel
    def edit(st):
        api = UsdSkel.BindingAPI(st.GetPrimAtPath("/root/Skeleton/Body/Body"))
        w = api.GetJointWeightsPrimvar()
        w.Set(list(w.Get())[:-6])
    with pytest.raises(USDInputError, match="jointIndices has .* jointWeights has"):
        read_character(_edit_copy(tmp_path, edit))


def test_nan_points(tmp_path):
    from pxr import UsdGeom
    def edit(st):
        m = UsdGeom.Mesh(st.GetPrimAtPath("/root/fedora01/fedora01"))
        p = np.array(m.GetPointsAttr().Get())
        p[7] = np.nan
        m.GetPointsAttr().Set(p.astype(np.float32))
    with pytest.raises(GeometryError, match="NaN"):
        read_character(_edit_copy(tmp_path, edit))


def test_missing_joints(tmp_path):
    from pxr import UsdSkel, Vt
    def edit(st):
        api = UsdSkel.BindingAPI(st.GetPrimAtPath("/root/Skeleton/Body/Body"))
        joints = list(UsdSkel.Skeleton(st.GetPrimAtPath("/root/Skeleton/Skeleton")).GetJointsAttr().Get())
        joints[3] = "Root/not_a_joint"
        api.CreateJointsAttr(Vt.TokenArray(joints))
    with pytest.raises(USDInputError, match="joints the skeleton lacks"):
        read_character(_edit_copy(tmp_path, edit))


def test_mesh_joint_order_is_remapped(tmp_path, ref_male):
    """A mesh with its own skel:joints order reads back to the same influences."""
    from pxr import UsdSkel, Vt
    def edit(st):
        api = UsdSkel.BindingAPI(st.GetPrimAtPath("/root/Skeleton/Body/Body"))
        joints = list(UsdSkel.Skeleton(st.GetPrimAtPath("/root/Skeleton/Skeleton")).GetJointsAttr().Get())
        perm = np.random.default_rng(0).permutation(len(joints))
        api.CreateJointsAttr(Vt.TokenArray([joints[i] for i in perm]))
        inv = np.argsort(perm)
        ind = api.GetJointIndicesPrimvar()
        ind.Set(Vt.IntArray.FromNumpy(inv[np.array(ind.Get())].astype(np.int32)))
    c = read_character(_edit_copy(tmp_path, edit))
    np.testing.assert_array_equal(c.body.joint_indices, ref_male.body.joint_indices)


def test_ngon_item_round_trip_with_uvs_and_orientation(tmp_path, ref_male):
    """An item with a pentagon, a quad and a triangle, indexed face-varying
    UVs and leftHanded orientation survives write -> read unchanged, and its
    triangles are wound outward in both cases."""
    from wearfit_usd.model import Mesh, Primvar
    pts = np.array([[0, 0, 0], [1, 0, 0], [1.3, 0.8, 0], [0.5, 1.3, 0], [-0.3, 0.8, 0],
                    [2, 0, 0], [2, 1, 0], [3, 0, 0]], float) * 0.1 + [0, 0, 0.5]
    counts = np.array([5, 4, 3])
    idx = np.array([0, 1, 2, 3, 4, 1, 5, 6, 2, 5, 7, 6])
    faces, t2p = triangulate(counts, idx, left_handed=True)
    uv = Primvar("st", "texCoord2f[]", "faceVarying", np.random.default_rng(1).random((12, 2)).astype(np.float32),
                 np.arange(12)[::-1].copy())
    item = Mesh("patch", pts, faces, counts, idx, t2p, primvars=[uv], left_handed=True)
    out = tmp_path / "ngon.usda"
    write_character(out, ref_male, items=[item])
    back = read_character(out).item("patch")
    np.testing.assert_array_equal(back.face_vertex_counts, counts)
    np.testing.assert_array_equal(back.face_vertex_indices, idx)
    np.testing.assert_array_equal(back.faces, faces)
    assert back.left_handed
    np.testing.assert_allclose(back.points, pts, atol=1e-6)
    st = next(p for p in back.primvars if p.name == "st")
    assert st.interpolation == "faceVarying"
    np.testing.assert_allclose(st.values, uv.values)
    np.testing.assert_array_equal(st.indices, uv.indices)


def test_shot_writer_appends_item_joints_that_usdskel_poses(tmp_path, ref_male):
    """A skeleton with two item joints appended (animate.item_joints): the
    body's animation comes in blocks, the item joints' per frame; UsdSkel
    poses a mesh skinned to them as our LBS does with the appended
    skinning matrices; a frame without its item joints leaves no file."""
    from pxr import Usd

    from wearfit_usd.animate.item_joints import ItemJoints, extend_skeleton
    from wearfit_usd.motion.skinning import Skinner, skinning_matrices
    rng = np.random.default_rng(5)
    skel = ref_male.skeleton
    n, j = 4, skel.n_joints
    local = _anim(skel, n, rng)
    world = skel.world_from_local(local)
    item = ref_male.items[0]
    parents = np.array([0, skel.n_joints - 1])
    bind = skel.bind_world[parents].copy()
    bind[:, 3, :3] = item.points[:2]
    joints = ItemJoints(["cloth_a", "cloth_b"], [item.name] * 2, parents, bind, j)
    skinned = item.copy_with_points(item.points)
    skinned.name = "skinned_copy"
    half = (np.arange(item.n_points) % 2).astype(float)
    skinned.joint_indices = np.stack([np.full(item.n_points, j), np.full(item.n_points, j + 1),
                                      np.zeros(item.n_points, int)], axis=1)
    skinned.joint_weights = np.stack([0.5 * half, 0.5 * (1 - half), np.full(item.n_points, 0.5)], axis=1)
    deltas = np.tile(np.eye(4), (n, 2, 1, 1))
    deltas[:, :, 3, :3] = rng.normal(0, 0.05, (n, 2, 3))
    out = tmp_path / "joints.usda"
    with ShotWriter(out, ref_male, [], fps=24, n_frames=n, skinned_items=[skinned],
                    skeleton=extend_skeleton(skel, joints)) as w:
        w.write_animation(local[:2], first_frame=0)
        w.write_animation(local[2:], first_frame=2)
        for f in range(n):
            w.write_item_joints(f, joints.world(deltas[f]))
            w.write_frame(f, [])
    stage = Usd.Stage.Open(str(out))
    assert validate_stage(stage) == []
    back = read_character(out)
    assert back.skeleton.n_joints == j + 2 and back.skeleton.joint_names[-2:] == ["cloth_a", "cloth_b"]
    lbs = Skinner(skinned.points, skinned.joint_indices, skinned.joint_weights, j + 2)
    for f in (1, 3):
        mats = np.concatenate([skinning_matrices(skel.bind_world, world[f]), deltas[f]])
        ref = transform_points(usdskel_skinned_points(stage, "/Root/Character/skinned_copy", f), back.to_internal)
        assert np.abs(ref - lbs(mats)).max() < 1e-4
    bad = tmp_path / "missing.usda"
    with pytest.raises(ValueError, match="item joints never written"):
        with ShotWriter(bad, ref_male, [], fps=24, n_frames=2, skinned_items=[skinned],
                        skeleton=extend_skeleton(skel, joints)) as w:
            w.write_animation(local[:2])
            w.write_item_joints(0, joints.world(deltas[0]))
            for f in range(2):
                w.write_frame(f, [])
    assert not bad.exists()
    with pytest.raises(ValueError, match="joints appended"):
        ShotWriter(tmp_path / "x.usda", ref_male, [], fps=24, n_frames=1, skeleton=ref_female_like(skel))
    assert not (tmp_path / "x.usda").exists()


def ref_female_like(skel):
    """A skeleton whose first joints are not ``skel``'s."""
    from wearfit_usd.model import Skeleton
    return Skeleton(skel.joint_names[::-1], skel.joint_paths[::-1], skel.parents, skel.bind_world, skel.rest_local)
