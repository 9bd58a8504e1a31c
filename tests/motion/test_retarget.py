"""Joint-name mapping and BVH -> USD skeleton retargeting on the real data."""
from __future__ import annotations

import json

import numpy as np
import pytest

from wearfit_usd.errors import InputError
from wearfit_usd.io.bvh import read_bvh
from wearfit_usd.io.usd import read_character
from wearfit_usd.motion.joint_maps import detect_convention, load_user_map, map_joints, normalize
from wearfit_usd.motion.retarget import retarget
from wearfit_usd.motion.skinning import skin_mesh


@pytest.fixture(scope="module")
def walk(bvh_dir):
    return read_bvh(bvh_dir / "cmu_07_01_walk.bvh")


@pytest.fixture(scope="module")
def cmu_body(usd_dir):
    return read_character(usd_dir / "body_male_cmu_rig.usdc")


def _j(skel, *names):
    for n in names:
        if n in skel.joint_names:
            return skel.joint_names.index(n)
    raise KeyError(names)


# ---------------------------------------------------------------- joint maps

def test_normalize_side_markers_and_prefixes():
    for name in ["thigh.L", "thigh_l", "l_thigh", "lThigh", "LeftThigh", "DEF-thigh.L",
                 "mixamorig:LeftThigh", "left_thigh", "Armature|thigh_L"]:
        assert normalize(name) == ("l", "thigh"), name
    assert normalize("LowerBack") == ("", "lowerback")  # not a side marker
    assert normalize("RThumb") == ("r", "thumb")


def test_conventions_detected_on_real_files(bvh_dir, ref_male, cmu_body):
    expect = {"cmu_07_01_walk.bvh": "cmu_motionbuilder",
              "cmu3dsmax_131_01_start_walk_stop.bvh": "cmu_3dsmax",
              "cmudaz_02_02_walk.bvh": "daz", "mhdefault_run01_pose.bvh": "makehuman_default"}
    for f, conv in expect.items():
        assert detect_convention(read_bvh(bvh_dir / f).joint_names)[0] == conv
    assert detect_convention(ref_male.skeleton.joint_names)[0] == "game_engine"
    assert detect_convention(cmu_body.skeleton.joint_names)[0] == "cmu_motionbuilder"


def test_map_cmu_and_daz_onto_game_engine(bvh_dir, ref_male):
    tgt = ref_male.skeleton.joint_names
    m = map_joints(read_bvh(bvh_dir / "cmu_07_01_walk.bvh").joint_names, tgt)
    expect = {"pelvis": "Hips", "spine_01": "LowerBack", "spine_03": "Spine1", "neck_01": "Neck",
              "head": "Head", "thigh_l": "LeftUpLeg", "calf_l": "LeftLeg", "foot_r": "RightFoot",
              "ball_l": "LeftToeBase", "clavicle_l": "LeftShoulder", "upperarm_l": "LeftArm",
              "lowerarm_r": "RightForeArm", "hand_l": "LeftHand"}
    assert {k: m.pairs[k] for k in expect} == expect
    assert "Root" in m.unmapped_target and "LHipJoint" in m.unmapped_source
    mx = map_joints(read_bvh(bvh_dir / "cmu3dsmax_131_01_start_walk_stop.bvh").joint_names, tgt)
    assert (mx.pairs["thigh_l"], mx.pairs["upperarm_l"], mx.pairs["hand_l"]) == \
        ("LeftHip", "LeftShoulder", "LeftWrist")
    dz = map_joints(read_bvh(bvh_dir / "cmudaz_02_02_walk.bvh").joint_names, tgt)
    assert (dz.pairs["pelvis"], dz.pairs["calf_r"], dz.pairs["upperarm_l"], dz.pairs["index_02_l"]) == \
        ("hip", "rShin", "lShldr", "lIndex2")
    mh = map_joints(read_bvh(bvh_dir / "mhdefault_run01_pose.bvh").joint_names, tgt)
    assert mh.unmapped_target == ["Root"] and mh.pairs["hand_l"] == "wrist.L"


def test_usd_to_usd_and_finger_name_mismatch(ref_male, cmu_body):
    m = map_joints(ref_male.skeleton.joint_names, cmu_body.skeleton.joint_names)
    assert m.pairs["LeftUpLeg"] == "thigh_l" and m.pairs["Spine1"] == "spine_03"
    assert m.pairs["LeftHandFinger1"] == "index_01_l"
    same = map_joints([n.replace("Finger1", "Index1") for n in cmu_body.skeleton.joint_names],
                      cmu_body.skeleton.joint_names)
    assert len(same) == 31 and same.pairs["RightHandFinger1"] == "RightHandIndex1"
    assert not same.unmapped_source and not same.unmapped_target


def test_other_conventions():
    mixamo = ["mixamorig:Hips", "mixamorig:Spine", "mixamorig:Spine1", "mixamorig:Spine2",
              "mixamorig:Neck", "mixamorig:Head", "mixamorig:LeftUpLeg", "mixamorig:LeftLeg",
              "mixamorig:LeftFoot", "mixamorig:LeftShoulder", "mixamorig:LeftArm",
              "mixamorig:LeftForeArm", "mixamorig:LeftHand"]
    smpl = ["pelvis", "left_hip", "left_knee", "left_ankle", "left_foot", "spine1", "spine2",
            "spine3", "neck", "head", "left_collar", "left_shoulder", "left_elbow", "left_wrist"]
    rigify = ["DEF-spine", "DEF-spine.001", "DEF-spine.002", "DEF-spine.003", "DEF-spine.004",
              "DEF-spine.006", "DEF-thigh.L", "DEF-shin.L", "DEF-foot.L", "DEF-shoulder.L",
              "DEF-upper_arm.L", "DEF-forearm.L", "DEF-hand.L"]
    a = map_joints(mixamo, smpl)
    assert a.pairs["left_knee"] == "mixamorig:LeftLeg" and a.pairs["spine3"] == "mixamorig:Spine2"
    assert a.pairs["left_shoulder"] == "mixamorig:LeftArm" and a.pairs["pelvis"] == "mixamorig:Hips"
    b = map_joints(rigify, mixamo)
    assert b.pairs["mixamorig:Hips"] == "DEF-spine" and b.pairs["mixamorig:Spine"] == "DEF-spine.001"
    assert b.pairs["mixamorig:LeftArm"] == "DEF-upper_arm.L"


def test_user_map(tmp_path, walk, ref_male):
    tgt = ref_male.skeleton.joint_names
    p = tmp_path / "map.json"
    p.write_text(json.dumps({"spine_02": "LowerBack", "neck_01": None}))
    um = load_user_map(p, walk.joint_names, tgt)
    m = map_joints(walk.joint_names, tgt, user_map=um)
    assert m.pairs["spine_02"] == "LowerBack" and "spine_01" not in m.pairs
    assert "neck_01" in m.unmapped_target and m.how["spine_02"] == "user"
    p.write_text('{"spine_02": "NoSuchJoint"}')
    with pytest.raises(InputError, match="NoSuchJoint"):
        load_user_map(p, walk.joint_names, tgt)
    p.write_text('{"spine_02": ')
    with pytest.raises(InputError, match="JSON"):
        load_user_map(p)
    p.write_text('["a", "b"]')
    with pytest.raises(InputError, match="object"):
        load_user_map(p)


# ---------------------------------------------------------------- retargeting

def _check_walk(char, walk, foot_names):
    sk = char.skeleton
    r = retarget(walk, sk, start=1)
    assert r.world.shape == (walk.n_frames - 1, sk.n_joints, 4, 4) and r.fps == pytest.approx(120)
    np.testing.assert_allclose(sk.world_from_local(r.local), r.world, atol=1e-9)
    pos = r.positions()
    root = _j(sk, "pelvis", "Hips")
    adv = pos[-1, root] - pos[0, root]
    assert np.linalg.norm(adv[[0, 2]]) > 2.0  # about 3.4 m walked
    fwd = adv[[0, 2]] / np.linalg.norm(adv[[0, 2]])
    lf, rf = (_j(sk, n) for n in foot_names)
    lrel = (pos[:, lf, [0, 2]] - pos[:, root, [0, 2]]) @ fwd
    rrel = (pos[:, rf, [0, 2]] - pos[:, root, [0, 2]]) @ fwd
    assert np.corrcoef(lrel, rrel)[0, 1] < -0.5  # feet move forward alternately
    assert np.ptp(lrel) > 0.3 and np.ptp(rrel) > 0.3
    # left foot stays on the left (no crossed legs)
    side = np.cross(np.r_[fwd[0], 0, fwd[1]], [0, 1, 0])  # right-hand direction
    assert np.all((pos[:, lf] - pos[:, rf]) @ side < 0.02)
    # skinned body: the lowest vertex stays near the bind floor
    frames = np.arange(0, r.n_frames, 10)
    skinned = skin_mesh(char.body, sk, r.world[frames])
    low = skinned[..., 1].min(axis=1) - char.body.points[:, 1].min()
    assert np.all(np.abs(low) < 0.06), low
    assert np.median(np.abs(low)) < 0.03
    # body does not collapse: height of the skinned body stays human
    assert np.all(np.ptp(skinned[..., 1], axis=1) > 1.5)
    return r, low


def test_walk_on_game_engine_body(ref_male, walk):
    _check_walk(ref_male, walk, ("foot_l", "foot_r"))


def test_walk_on_cmu_rig_body(cmu_body, walk):
    _check_walk(cmu_body, walk, ("LeftFoot", "RightFoot"))


def test_arms_held_high_go_above_head(bvh_dir, ref_male):
    clip = read_bvh(bvh_dir / "cmu_05_12_dance_arms_held_high.bvh")
    sk = ref_male.skeleton
    r = retarget(clip, sk, start=1, fps=30)
    pos = r.positions()
    head = _j(sk, "head")
    above = (pos[:, _j(sk, "hand_l"), 1] > pos[:, head, 1]) | (pos[:, _j(sk, "hand_r"), 1] > pos[:, head, 1])
    assert above.mean() > 0.05
    assert not above.all()


def test_direction_mode_bones_follow_the_clip(walk, ref_male):
    sk = ref_male.skeleton
    m = map_joints(walk.joint_names, sk.joint_names)
    r = retarget(walk, sk, mapping=m, start=1, end=200)
    _, gp = walk.global_rotations_positions(np.arange(1, 200))
    pos = r.positions()
    for a, b in [("upperarm_l", "lowerarm_l"), ("thigh_r", "calf_r"), ("lowerarm_r", "hand_r")]:
        ta, tb = _j(sk, a), _j(sk, b)
        sa, sb = walk.index(m.pairs[a]), walk.index(m.pairs[b])
        dt = pos[:, tb] - pos[:, ta]
        ds = gp[:, sb] - gp[:, sa]
        cos = np.sum(dt * ds, -1) / np.linalg.norm(dt, axis=-1) / np.linalg.norm(ds, axis=-1)
        assert cos.min() > 0.999, (a, cos.min())
    # bone lengths are the target's
    i, p = _j(sk, "calf_l"), _j(sk, "thigh_l")
    bind_len = np.linalg.norm(sk.bind_world[i, 3, :3] - sk.bind_world[p, 3, :3])
    np.testing.assert_allclose(np.linalg.norm(pos[:, i] - pos[:, p], axis=-1), bind_len, atol=1e-6)


def _lean(top, bottom):
    """Degrees of (top - bottom) from the vertical (Y up)."""
    v = np.asarray(top) - np.asarray(bottom)
    return np.degrees(np.arctan2(np.linalg.norm(v[..., [0, 2]], axis=-1), v[..., 1]))


def test_posture_mode_keeps_the_upright_stance(walk, ref_female):
    """At the clip's rest the hips-to-head chain is in its bind pose while
    the limbs take the clip's rest directions (a T-pose: arms out)."""
    import copy
    sk = ref_female.skeleton
    rest = copy.copy(walk)
    rest.values = walk.values[:3].copy()
    rest.n_frames = 3
    rest.values[:, 3:] = 0.0
    r = retarget(rest, sk)
    axial = [_j(sk, n) for n in ("pelvis", "spine_01", "spine_02", "spine_03", "neck_01", "head")]
    np.testing.assert_allclose(r.world[:, axial, :3, :3],
                               np.broadcast_to(sk.bind_world[axial, :3, :3], (3, len(axial), 3, 3)), atol=1e-6)
    pos = r.positions()
    for side in "lr":
        # the upper arm points along the clip's rest upper arm: sideways (T-pose), not hanging (A-pose bind)
        arm = pos[0, _j(sk, f"lowerarm_{side}")] - pos[0, _j(sk, f"upperarm_{side}")]
        assert abs(arm[1]) / np.linalg.norm(arm) < 0.1, arm


def test_posture_chain_found_with_or_without_the_pairing(walk, ref_female):
    from wearfit_usd.motion.retarget import retarget_stream
    sk = ref_female.skeleton
    paired = retarget_stream(walk, sk, start=1, end=10)
    named = retarget_stream(walk, sk, mapping=map_joints(walk.joint_names, sk.joint_names), start=1, end=10)
    want = {"pelvis", "spine_01", "spine_02", "spine_03", "neck_01", "head"}
    for s in (paired, named):
        assert {sk.joint_names[j] for j in np.flatnonzero(s.posture)} == want
    assert not retarget_stream(walk, sk, start=1, end=10, mode="direction").posture.any()
    assert retarget_stream(walk, sk, start=1, end=10, mode="bind").posture.all()


@pytest.mark.parametrize("clip, baseline_off", [("cmu_07_01_walk.bvh", 3.0), ("cmu_09_11_run.bvh", 5.0),
                                                ("cmu_02_04_jump_balance.bvh", 3.0)])
def test_posture_mode_leans_the_torso_as_the_clip_does(bvh_dir, ref_female, clip, baseline_off):
    """The torso's lean (pelvis to neck, from the vertical, against its rest
    stance's) is the clip's: with the bones pointed along the clip's
    ("direction") it was off by 3.9 (walk), 7.0 (run) and 4.7 (jump)
    degrees: CMU's neck and lower back bones lean otherwise than
    MakeHuman's in their upright rests."""
    m = read_bvh(bvh_dir / clip)
    _, gp = m.global_rotations_positions(np.arange(1, m.n_frames))
    rest = m.rest_global_transforms()[:, 3, :3]
    hips, neck = m.index("Hips"), m.index("Neck")
    want = np.median(_lean(gp[:, neck], gp[:, hips]) - _lean(rest[neck], rest[hips]))
    sk = ref_female.skeleton
    p, n = _j(sk, "pelvis"), _j(sk, "neck_01")
    bind = _lean(sk.bind_world[n, 3, :3], sk.bind_world[p, 3, :3])
    got = {}
    for mode in ("posture", "direction"):
        pos = retarget(m, sk, start=1, mode=mode).positions()
        got[mode] = np.median(_lean(pos[:, n], pos[:, p])) - bind
    assert abs(got["posture"] - want) < 2.0, (got, want)
    assert abs(got["direction"] - want) > baseline_off, (got, want)


def test_clip_rest_gives_bind_pose_in_bind_mode(walk, ref_male, tmp_path):
    """A T-pose clip at its rest leaves the A-pose body in its bind pose."""
    import copy
    sk = ref_male.skeleton
    rest = copy.copy(walk)
    rest.values = walk.values[:5].copy()
    rest.n_frames = 5
    rest.values[:, 3:] = 0.0  # every rotation zero: the clip's rest
    r = retarget(rest, sk, mode="bind")
    rot = r.world[..., :3, :3]
    np.testing.assert_allclose(rot, np.broadcast_to(sk.bind_world[:, :3, :3], rot.shape), atol=1e-5)
    # positions: bind, up to the root placement
    pos = r.positions() - r.positions()[:, [_j(sk, "pelvis")]]
    bind = sk.bind_world[:, 3, :3] - sk.bind_world[_j(sk, "pelvis"), 3, :3]
    joints = [j for j in range(sk.n_joints) if sk.joint_names[j] != "Root"]
    np.testing.assert_allclose(pos[:, joints], np.broadcast_to(bind[joints], pos[:, joints].shape),
                               atol=1e-5)
    hand, shoulder = _j(sk, "hand_l"), _j(sk, "upperarm_l")
    assert (r.positions()[:, hand, 1] < r.positions()[:, shoulder, 1] - 0.2).all()  # arms down


def test_resampling_and_range(walk, cmu_body):
    sk = cmu_body.skeleton
    full = retarget(walk, sk, start=1, end=121)
    half = retarget(walk, sk, start=1, end=121, fps=30)
    assert half.fps == 30 and half.n_frames == 30
    np.testing.assert_allclose(half.world, full.world[::4], atol=1e-9)
    np.testing.assert_allclose(half.times, np.arange(30) / 30)
    odd = retarget(walk, sk, start=1, end=121, fps=48)  # 2.5 source frames per output frame
    assert odd.n_frames == 48
    mid = odd.world[1, :, 3, :3]  # source frame 3.5: between native frames 2 and 3 (from start)
    a, b = full.world[2, :, 3, :3], full.world[3, :, 3, :3]
    assert np.abs(mid - (a + b) / 2).max() < 0.01
    with pytest.raises(InputError):
        retarget(walk, sk, start=400)
