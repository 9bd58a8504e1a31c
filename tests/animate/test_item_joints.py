"""Joints of the items' own (animate.item_joints): known answers on a
synthetic hanging strip, the shot's skeleton and animation as UsdSkel reads
them, and the ponytail of the arms-held-high dance."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.conftest import BVH_DIR, USD_DIR
from wearfit_usd.animate.item_joints import (
    SKIRT_VERTICES_PER_JOINT,
    HeldOut,
    ItemJoints,
    JointFit,
    choose_items,
    extend_skeleton,
    plan_item_joints,
)
from wearfit_usd.dress.item_weights import weight_matrix
from wearfit_usd.model import Mesh, Skeleton
from wearfit_usd.motion.skinning import Skinner


def _skeleton():
    """root (at the origin) with two children, 'left' and 'right', 0.1 m to each side."""
    bind = np.tile(np.eye(4), (3, 1, 1))
    bind[1, 3, :3] = [0.1, 0.0, 0.0]
    bind[2, 3, :3] = [-0.1, 0.0, 0.0]
    local = bind.copy()
    return Skeleton(["root", "left", "right"], ["root", "root/left", "root/right"], np.array([-1, 0, 0]), bind, local)


def _strip(n_rows=12, n_cols=8):
    """A hanging strip 0.3 m wide, 0.6 m long (y from 0 down), its top row
    on the two children half and half; with (M,) cloth weights rising from
    0 at the top to 1 below 0.15 m."""
    x, y = np.meshgrid(np.linspace(-0.15, 0.15, n_cols), np.linspace(0.0, -0.6, n_rows))
    pts = np.stack([x.ravel(), y.ravel(), np.full(x.size, 0.1)], axis=1)
    quads = [(r * n_cols + c, r * n_cols + c + 1, (r + 1) * n_cols + c + 1, (r + 1) * n_cols + c)
             for r in range(n_rows - 1) for c in range(n_cols - 1)]
    faces = np.array([f for a, b, c, d in quads for f in ((a, b, c), (a, c, d))], dtype=np.int64)
    m = Mesh("strip", pts, faces, np.full(len(quads), 4), np.array(quads).ravel(), np.repeat(np.arange(len(quads)), 2))
    side = (pts[:, 0] > 0).astype(float)
    m.joint_indices = np.stack([np.ones(len(pts), int), np.full(len(pts), 2)], axis=1)
    m.joint_weights = np.stack([side, 1 - side], axis=1)
    blend = np.clip(-pts[:, 1] / 0.15, 0.0, 1.0)
    return m, blend


def _rigid(rotvec, t):
    d = np.eye(4)
    d[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix().T   # row vectors
    d[3, :3] = t
    return d


def test_the_plan_keeps_the_attached_part_and_hangs_the_rest_from_the_common_parent():
    skel = _skeleton()
    strip, blend = _strip()
    joints, (out,) = plan_item_joints([strip], blend, skel)
    n = joints.n_joints
    assert n == 2   # 84 loose vertices / 40 per joint
    assert joints.n_body == 3 and list(joints.parents) == [0, 0]   # the LCA of left and right
    assert joints.names == ["strip_joint00", "strip_joint01"] and joints.items == ["strip", "strip"]
    w = weight_matrix(out.joint_indices, out.joint_weights, 3 + n).toarray()
    assert np.allclose(w.sum(axis=1), 1.0)
    top = blend == 0
    assert np.allclose(w[top, 1], strip.joint_weights[top, 0]) and np.allclose(w[top, 3:], 0.0)
    low = blend == 1
    assert np.allclose(w[low, :3], 0.0) and np.allclose(w[low, 3:].sum(axis=1), 1.0)
    mid = (blend > 0) & (blend < 1)
    assert np.allclose(w[mid, 3:].sum(axis=1), blend[mid])
    # bind transforms at the clusters' centres, inside the strip's extent
    c = joints.bind_world[:, 3, :3]
    assert (c[:, 1] < 0).all() and (np.abs(c[:, 0]) < 0.15).all()


def test_the_fit_recovers_a_rigid_swing_exactly():
    """The hanging part swung rigidly (about the strip's top, body at rest):
    every item joint's transform is that swing."""
    skel = _skeleton()
    strip, blend = _strip()
    blend = (blend > 0).astype(float)           # all loose rows fully on the item joints
    joints, (out,) = plan_item_joints([strip], blend, skel)
    swing = _rigid([0.4, 0.1, -0.2], [0.02, -0.01, 0.05])
    y = out.points.copy()
    loose = blend > 0
    y[loose] = y[loose] @ swing[:3, :3] + swing[3, :3]
    fit = JointFit(out.points, out.joint_indices, out.joint_weights, joints)
    d = fit(y, np.tile(np.eye(4), (3, 1, 1)))
    assert np.allclose(d, swing[None], atol=1e-9)
    posed = Skinner(out.points, out.joint_indices, out.joint_weights, 3 + joints.n_joints)(
        np.concatenate([np.tile(np.eye(4), (3, 1, 1)), d]))
    assert np.abs(posed - y).max() < 1e-9


def test_the_fit_follows_a_bend_better_than_one_joint_and_its_sweeps_help():
    """The strip bent (each row turned by an angle growing down it): the
    blended joints follow it; the sweeps lower the error of
    the clusters' rigid fits."""
    skel = _skeleton()
    strip, blend = _strip(24, 8)
    joints, (out,) = plan_item_joints([strip], blend, skel)
    assert joints.n_joints == 5   # 184 loose vertices / 40
    y = out.points.copy()
    depth = -out.points[:, 1]
    ang = 0.8 * depth                                   # radians: 0.48 at the hem
    y[:, 1] = -np.sin(np.pi / 2 - ang) * depth          # the strip curls forward (+z)
    y[:, 2] = 0.1 + np.cos(np.pi / 2 - ang) * depth * 0.8
    mats = np.tile(np.eye(4), (3, 1, 1))
    skin = Skinner(out.points, out.joint_indices, out.joint_weights, 3 + joints.n_joints)
    errs = []
    for sweeps in (0, 2):
        d = JointFit(out.points, out.joint_indices, out.joint_weights, joints, sweeps=sweeps)(y, mats)
        errs.append(np.linalg.norm(skin(np.concatenate([mats, d])) - y, axis=1)[blend > 0])
    plain = np.linalg.norm(strip.points - y, axis=1)[blend > 0]
    assert errs[1].mean() < errs[0].mean() < plain.mean()
    assert np.percentile(errs[1], 95) < 0.25 * np.percentile(plain, 95), (np.percentile(errs[1], 95),
                                                                           np.percentile(plain, 95))


def _floor(size=1.0, n=6):
    """A flat body: a square grid in the y = 0 plane, its normal +y."""
    x, z = np.meshgrid(np.linspace(-size, size, n), np.linspace(-size, size, n))
    pts = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)
    faces = []
    for r in range(n - 1):
        for c in range(n - 1):
            a, b, d, e = r * n + c, r * n + c + 1, (r + 1) * n + c, (r + 1) * n + c + 1
            faces += [(a, d, b), (b, d, e)]     # wound so the normals point up (+y)
    return np.array(faces, dtype=np.int64), pts


def test_held_out_moves_the_cloth_off_the_body_by_its_clearance():
    """Known answers over a flat body, at rest and moved: touching or
    inside -> the full push, half the reach -> half, beyond the reach ->
    unmoved, along the normal; the same as a brute-force closest point."""
    faces, body = _floor()
    pts = np.array([[0.1, 0.0, 0.2], [0.3, 0.01, -0.1], [-0.2, 0.03, 0.0], [0.0, -0.005, 0.3], [0.2, 0.5, 0.2]])
    held = HeldOut(faces, body, push=0.015, reach=0.02)
    for lift in (0.0, 0.25, -0.1):               # the body moved up and down between calls
        moved = body + [0.0, lift, 0.0]
        out = held(pts + [0.0, lift, 0.0], moved)
        assert np.allclose(out[:, [0, 2]], pts[:, [0, 2]])
        assert np.allclose(out[:, 1] - lift - pts[:, 1], [0.015, 0.0075, 0.0, 0.015, 0.0])
    # a tilted body: the push along its normal
    rot = Rotation.from_rotvec([0.0, 0.0, 0.5]).as_matrix()
    out = held(pts[:1] @ rot.T, body @ rot.T)
    assert np.allclose(out - pts[:1] @ rot.T, 0.015 * (np.array([[0.0, 1.0, 0.0]]) @ rot.T))


def test_the_fit_holds_the_copy_out_of_the_body_it_lies_on():
    """A strip lying flat on a body, its hanging part fitted with the body
    given: the fitted joints carry it ``push`` off the body (a miss of the
    rigid joints then falls outside); without the body, onto the cloth."""
    skel = _skeleton()
    strip, blend = _strip()
    pts = strip.points.copy()
    strip.points = np.stack([pts[:, 0], np.zeros(len(pts)), pts[:, 1] - 0.2], axis=1)   # lying in y = 0
    blend = (blend > 0).astype(float)
    joints, (out,) = plan_item_joints([strip], blend, skel)
    faces, body = _floor()
    mats = np.tile(np.eye(4), (3, 1, 1))
    skin = Skinner(out.points, out.joint_indices, out.joint_weights, 3 + joints.n_joints)
    fit = JointFit(out.points, out.joint_indices, out.joint_weights, joints,
                   held_out=HeldOut(faces, body, push=0.01, reach=0.02))
    on = skin(np.concatenate([mats, fit(out.points, mats)]))
    held = skin(np.concatenate([mats, fit(out.points, mats, body)]))
    loose = blend > 0
    assert np.abs(on - out.points).max() < 1e-9
    assert np.allclose(held[loose, 1], 0.01, atol=1e-9) and np.allclose(held[loose][:, [0, 2]],
                                                                        out.points[loose][:, [0, 2]])


def test_skirts_get_more_joints():
    skel = _skeleton()
    strip, blend = _strip(24, 8)
    loose = int((blend > 0).sum())
    plain, _ = plan_item_joints([strip], blend, skel)
    skirt, _ = plan_item_joints([strip], blend, skel, skirts={"strip"})
    assert plain.n_joints == 5 and skirt.n_joints == round(loose / SKIRT_VERTICES_PER_JOINT) > 3 * plain.n_joints


def test_extend_skeleton_appends_children_at_rest_on_their_bind():
    skel = _skeleton()
    bind = np.tile(np.eye(4), (2, 1, 1))
    bind[:, 3, :3] = [[0.0, -0.2, 0.1], [0.05, -0.5, 0.1]]
    joints = ItemJoints(["a", "b"], ["strip", "strip"], np.array([0, 1]), bind, 3)
    ext = extend_skeleton(skel, joints)
    assert ext.n_joints == 5 and ext.joint_paths[3:] == ["root/a", "root/left/b"]
    assert list(ext.parents) == [-1, 0, 0, 0, 1]
    assert np.allclose(ext.rest_world()[3:], bind)
    assert np.allclose(joints.world(np.tile(np.eye(4), (2, 1, 1))), bind)
    with pytest.raises(ValueError, match="body joints"):
        extend_skeleton(skel, ItemJoints(["a"], ["s"], np.array([0]), bind[:1], 4))


def test_bad_cloth_weights_are_refused():
    strip, blend = _strip()
    with pytest.raises(ValueError, match="cloth weights for"):
        plan_item_joints([strip], blend[:-1], _skeleton())


def test_choose_items_keeps_joints_only_where_they_follow_the_cloth_better():
    """Example poses in which the hanging part swings away from the skin
    (the joints follow it: kept) and in which it follows the skin exactly
    (nothing to gain: dropped)."""
    import trimesh
    skel = _skeleton()
    strip, blend = _strip()
    box = trimesh.creation.box(extents=(0.2, 0.4, 0.1))     # a body behind the strip (z -0.05..0.05)
    box.apply_translation([0.0, -0.3, 0.0])
    body_pts, body_faces = np.asarray(box.vertices), np.asarray(box.faces)
    mats = np.tile(np.eye(4), (5, 3, 1, 1))
    bodies = np.repeat(body_pts[None], 5, axis=0)
    loose = blend > 0
    swung = np.repeat(strip.points[None], 5, axis=0)
    for f in range(5):
        s = _rigid([-0.1 * f, 0.0, 0.0], [0.0, 0.0, 0.0])   # the hem swings forward, away from the body
        swung[f, loose] = strip.points[loose] @ s[:3, :3] + s[3, :3]
    mask = np.zeros(strip.n_points, dtype=bool)
    kept, rep_kept = choose_items([strip], blend, skel, (mats, bodies, swung, mask), body_faces, body_pts)
    assert rep_kept["strip"]["on"] and np.array_equal(kept, blend), rep_kept
    assert rep_kept["strip"]["gap_joints_mm"] < 0.1 * rep_kept["strip"]["gap_skin_mm"]
    still = np.repeat(strip.points[None], 5, axis=0)
    dropped, rep = choose_items([strip], blend, skel, (mats, bodies, still, mask), body_faces, body_pts)
    assert not rep["strip"]["on"] and not dropped.any(), rep
    # the plan passed in (as animate does) chooses the same
    plan = plan_item_joints([strip], blend, skel)
    again, rep2 = choose_items([strip], blend, skel, (mats, bodies, swung, mask), body_faces, body_pts, plan=plan)
    assert rep2 == rep_kept and np.array_equal(again, kept)


@pytest.mark.slow
def test_the_ponytail_hangs_on_joints_of_its_own_in_the_arms_held_high_dance(tmp_path, ref_female):
    """The CMU dance with the arms held high, where the head tips back:
    skinned with the weights of the skin it hangs over, ``ponytail01``'s
    copy went into the back (5.33 % new penetrations against the cloth
    redress's 1.19 %; issue 19 asks within 1 point). On joints of its own
    animated from the cloth: 0.19 %. The shot's Skeleton and SkelAnimation
    carry the joints, and UsdSkel poses the copy as the measure did."""
    from pxr import Usd, UsdGeom, UsdSkel

    from tests.usdskel_reference import usdskel_skinned_points
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    from wearfit_usd.io.usd_validate import validate_stage
    target = read_character(USD_DIR / "body_female_thin.usdc")
    clip = read_bvh(BVH_DIR / "cmu_05_12_dance_arms_held_high.bvh")
    out = tmp_path / "dance.usdc"
    rep = animate(ref_female, target, clip, out, AnimateOptions(start=1, end=241, fps=30, items="both",
                                                                 measure_every=2))
    assert rep.item_joints == {"ponytail01_skinned": 24}, rep.item_joints
    w = rep.motion_worst
    skinned, redress = w["ponytail01_skinned"]["new_pen_pct"]["value"], w["ponytail01"]["new_pen_pct"]["value"]
    assert skinned <= redress + 1.0, (skinned, redress)
    stage = Usd.Stage.Open(str(out))
    assert validate_stage(stage) == []
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath("/Root/Character/Skeleton"))
    joints = list(skel.GetJointsAttr().Get())
    assert len(joints) == target.skeleton.n_joints + 24
    assert joints[-1].endswith("/ponytail01_skinned_joint23") and "/head/" in joints[-1]
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/Root/Character/Animation"))
    assert list(anim.GetJointsAttr().Get()) == joints
    # UsdSkel's posed copy lies on the cloth's ponytail (the point cache)
    for f in (20, 40, 56):
        cached = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Items/ponytail01")).GetPointsAttr().Get(f))
        posed = usdskel_skinned_points(stage, "/Root/Character/ponytail01_skinned", f)
        d = np.linalg.norm(posed - cached, axis=1)
        # measured 71-75 mm (the skin's weights: 126-136 mm); the cloth's strands part where rigid joints cannot
        assert np.percentile(d, 95) < 0.1, (f, np.percentile(d, 95))


@pytest.mark.slow
def test_the_long_skirt_follows_its_cloth_on_joints_of_its_own_in_a_walk(tmp_path):
    """``ref_female_longskirt`` on a man's body in the CMU walk, where the
    narrow skirt rides up in stride: skinned with each side's skin it went
    into the legs (2.65 % new penetrations against the cloth redress's
    0.56 %, stretch p99 3.99x); on joints of its own fitted to the cloth
    held out from the legs, 0.70 % and 1.48x (128 joints)."""
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    ref = read_character(USD_DIR / "ref_female_longskirt.usda")
    target = read_character(USD_DIR / "body_male_heavy.usdc")
    clip = read_bvh(BVH_DIR / "cmu_07_01_walk.bvh")
    rep = animate(ref, target, clip, tmp_path / "walk.usdc",
                  AnimateOptions(start=1, end=241, fps=30, items="both", measure_every=2))
    assert rep.item_joints.get("long_skirt_skinned", 0) >= 48, rep.item_joints
    w = rep.motion_worst
    skinned, redress = w["long_skirt_skinned"]["new_pen_pct"]["value"], w["long_skirt"]["new_pen_pct"]["value"]
    assert skinned <= redress + 1.0, (skinned, redress)
    assert w["long_skirt_skinned"]["stretch_p99"]["value"] < 2.0


@pytest.mark.slow
def test_no_item_joints_keeps_the_skeleton_of_the_target(tmp_path):
    """``--no-item-joints``: the skinned copies keep the skin's weights and
    the shot's Skeleton and SkelAnimation hold the target's joints only."""
    from pxr import Usd, UsdSkel

    from wearfit_usd.cli import main
    from wearfit_usd.io.usd import read_character
    out = tmp_path / "plain.usdc"
    target = USD_DIR / "body_female_thin.usdc"
    assert main(["animate", str(USD_DIR / "ref_female.usda"), str(target),
                 str(BVH_DIR / "cmu_05_12_dance_arms_held_high.bvh"), "-o", str(out), "--start", "1", "--end", "41",
                 "--items", "skinned", "--no-item-joints", "-q"]) == 0
    stage = Usd.Stage.Open(str(out))
    joints = list(UsdSkel.Skeleton(stage.GetPrimAtPath("/Root/Character/Skeleton")).GetJointsAttr().Get())
    assert len(joints) == read_character(target).skeleton.n_joints
    assert not any("_joint" in j.rsplit("/", 1)[-1] for j in joints)
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/Root/Character/Animation"))
    assert list(anim.GetJointsAttr().Get()) == joints
