"""BVH reader/writer on the real clips of ../shared/data/bvh and small hand-made files."""
from __future__ import annotations

import numpy as np
import pytest

from wearfit_usd.errors import BVHError
from wearfit_usd.io.bvh import CMU_UNIT_M, read_bvh, write_bvh
from wearfit_usd.transforms import euler_to_matrix, matrix_to_euler

# data card table: file -> (frames, joints, end sites, channels, fps, rotation order histogram)
CARD = {
    "cmu3dsmax_131_01_start_walk_stop.bvh": (994, 31, 7, 96, 120, {"ZYX": 19, "ZXY": 12}),
    "cmu_02_04_jump_balance.bvh": (484, 31, 7, 96, 120, {"ZYX": 31}),
    "cmu_02_05_punch_strike.bvh": (1855, 31, 7, 96, 120, {"ZYX": 31}),
    "cmu_05_02_dance_pirouette.bvh": (1124, 31, 7, 96, 120, {"ZYX": 31}),
    "cmu_05_12_dance_arms_held_high.bvh": (1355, 31, 7, 96, 120, {"ZYX": 31}),
    "cmu_07_01_walk.bvh": (317, 31, 7, 96, 120, {"ZYX": 31}),
    "cmu_09_11_run.bvh": (166, 31, 7, 96, 120, {"ZYX": 31}),
    "cmudaz_02_02_walk.bvh": (299, 43, 14, 132, 120, {"ZYX": 1, "ZXY": 42}),
    "mhdefault_run01_pose.bvh": (1, 163, 49, 891, 24, {"XYZ": 163}),
}


@pytest.fixture(scope="module")
def clips(bvh_dir):
    return {name: read_bvh(bvh_dir / name) for name in CARD}


def test_every_file_matches_data_card(bvh_dir, clips):
    assert sorted(p.name for p in bvh_dir.glob("*.bvh")) == sorted(CARD)
    for name, (frames, joints, ends, chans, fps, orders) in CARD.items():
        m = clips[name]
        s = m.summary()
        assert (s["frames"], s["joints"], s["end_sites"], s["channels"]) == (frames, joints, ends, chans), name
        assert m.values.shape == (frames, chans)
        assert abs(s["fps"] - fps) < 0.01, (name, s["fps"])
        assert s["rotation_orders"] == orders, name
        assert np.all(m.parents[1:] < np.arange(1, joints)) and m.parents[0] == -1
        assert s["kind"] == "bvh" and s["duration_s"] == pytest.approx(frames / fps, rel=1e-3)


def test_units_axes_and_dialects(clips):
    walk = clips["cmu_07_01_walk.bvh"]
    assert walk.scale == pytest.approx(CMU_UNIT_M) and walk.dialect == "cmu_motionbuilder"
    assert clips["cmu3dsmax_131_01_start_walk_stop.bvh"].dialect == "cmu_3dsmax"
    daz = clips["cmudaz_02_02_walk.bvh"]
    assert daz.scale == pytest.approx(0.01) and daz.dialect == "daz"
    mh = clips["mhdefault_run01_pose.bvh"]
    assert mh.scale == pytest.approx(0.1) and mh.up_axis == "Z" and mh.dialect == "makehuman_default"
    # the raw 3dsMax hierarchy: CRLF and LF lines both parsed; arms use ZXY
    mx = clips["cmu3dsmax_131_01_start_walk_stop.bvh"]
    assert mx.rotation_orders[mx.index("LeftShoulder")] == "ZXY"
    assert mx.rotation_orders[mx.index("LeftHip")] == "ZYX"


def test_bone_lengths_constant_over_frames(clips):
    for name, m in clips.items():
        g = m.global_positions()
        child = np.arange(1, m.n_joints)
        seg = np.linalg.norm(g[:, child] - g[:, m.parents[child]], axis=-1)  # (F, J-1)
        if name.startswith("mh"):  # non-root position channels may stretch bones
            continue
        rest = np.linalg.norm(m.offsets[child], axis=-1)
        assert np.abs(seg - rest).max() < 1e-9, name


def _height_above_floor(m, first=1):
    """Mean root height above the lowest foot point of the clip (m)."""
    g = m.global_positions()[first:]
    ends = m.end_site_positions()[first:]
    floor = min(g[..., 1].min(), ends[..., 1].min())
    return float(g[:, 0, 1].mean() - floor), floor


def test_daz_and_cmu_walks_give_similar_heights(clips):
    h_cmu, _ = _height_above_floor(clips["cmu_07_01_walk.bvh"])
    h_daz, _ = _height_above_floor(clips["cmudaz_02_02_walk.bvh"])
    assert 0.85 < h_cmu < 1.05, h_cmu
    # Daz's "hip" joint sits lower in the pelvis than CMU's Hips (card: ~78 cm)
    assert 0.75 < h_daz < 1.0, h_daz
    assert abs(h_cmu - h_daz) < 0.2
    for m in (clips["cmu_07_01_walk.bvh"], clips["cmudaz_02_02_walk.bvh"]):
        assert 1.3 < m.summary()["height_m"] < 1.9


def test_feet_near_floor_in_walks(clips):
    # CMU files (and the Daz conversion of a CMU trial) start with a T-pose frame: skip it
    for name, feet in [("cmu_07_01_walk.bvh", ("LeftToeBase", "RightToeBase")),
                       ("cmudaz_02_02_walk.bvh", ("lFoot", "rFoot")),
                       ("cmu3dsmax_131_01_start_walk_stop.bvh", ("LeftToe", "RightToe"))]:
        m = clips[name]
        g = m.global_positions()[1:]
        idx = [m.index(f) for f in feet]
        lowest_foot = g[:, idx, 1].min(axis=1)  # (F,) lower of the two feet
        if name.startswith("cmudaz"):
            # this capture's floor rises ~10 cm over the 3.6 m walk (the head
            # rises too): remove the linear trend before comparing
            t = np.arange(len(lowest_foot))
            lowest_foot = lowest_foot - np.polyval(np.polyfit(t, lowest_foot, 1), t)
        # in every frame of a walk one foot is on the ground: its height
        # stays within a few cm of the clip's lowest foot point
        spread = np.percentile(lowest_foot, 98) - np.percentile(lowest_foot, 2)
        assert spread < 0.08, (name, spread)
        # the floor is at y ~ 0 in these clips
        assert -0.1 < g[:, idx, 1].min() < 0.1, name
        # the root advances (walking, metres)
        assert np.linalg.norm(g[-1, 0, [0, 2]] - g[0, 0, [0, 2]]) > 0.5


def test_makehuman_z_up_pose_comes_out_y_up(clips):
    m = clips["mhdefault_run01_pose.bvh"]
    g = m.global_positions()[0]
    head, root = g[m.index("head")], g[m.index("root")]
    assert head[1] - root[1] > 0.4  # head well above the root along +Y
    toes = g[[i for i, n in enumerate(m.joint_names) if n.startswith("toe")], 1]
    assert toes.min() < root[1] - 0.6  # feet well below
    # rest pose: left foot on +X, face forward (+Z): eyes in front of the head joint
    rest = m.rest_global_transforms()[:, 3, :3]
    assert rest[m.index("foot.L"), 0] > 0 > rest[m.index("foot.R"), 0]
    assert rest[m.index("eye.L"), 2] > rest[m.index("head"), 2]
    assert np.ptp(rest[:, 1]) > 1.4  # vertical extent in metres along Y


def test_cmu_rest_frame_is_t_pose(clips):
    m = clips["cmu_07_01_walk.bvh"]
    g = m.global_positions(0)[0]
    arm = g[m.index("LeftHand")] - g[m.index("LeftArm")]
    assert arm[0] > 0.4 and abs(arm[1]) < 0.1  # left arm along +X
    assert g[m.index("Head"), 1] > g[m.index("Hips"), 1] + 0.4


HAND = """HIERARCHY
ROOT a
{{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition {rot}
  JOINT b
  {{
    OFFSET 0 1 0
    CHANNELS 3 {rot}
    End Site
    {{
      OFFSET 0 0 1
    }}
  }}
}}
MOTION
Frames: 1
Frame Time: 0.04
1 2 3 {angles} 0 0 0
"""


def _rx(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


@pytest.mark.parametrize("order", ["ZYX", "ZXY", "XYZ"])
def test_hand_computed_chain(tmp_path, order):
    angles = {"X": 30.0, "Y": -50.0, "Z": 70.0}
    rot = " ".join(f"{a}rotation" for a in order)
    vals = " ".join(str(angles[a]) for a in order)
    p = tmp_path / "chain.bvh"
    p.write_text(HAND.format(rot=rot, angles=vals))
    m = read_bvh(p, scale=1.0)
    R = {"X": _rx, "Y": _ry, "Z": _rz}
    M = R[order[0]](angles[order[0]]) @ R[order[1]](angles[order[1]]) @ R[order[2]](angles[order[2]])
    g = m.global_positions()[0]
    # column-vector maths by hand: child at root + M @ (0, 1, 0)
    np.testing.assert_allclose(g[0], [1, 2, 3], atol=1e-12)
    np.testing.assert_allclose(g[1], np.array([1, 2, 3]) + M @ [0, 1, 0], atol=1e-12)
    end = m.end_site_positions()[0, 0]
    np.testing.assert_allclose(end, g[1] + M @ [0, 0, 1], atol=1e-12)
    # row-vector 4x4: world[1] = local[1] @ world[0]; rotation block = M.T
    w = m.global_transforms()[0]
    np.testing.assert_allclose(w[0, :3, :3], M.T, atol=1e-12)
    np.testing.assert_allclose(np.array([0, 0, 1, 1.0]) @ w[1], np.append(end, 1), atol=1e-12)


def test_euler_roundtrip_all_orders():
    rng = np.random.default_rng(1)
    for order in ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]:
        a = rng.uniform(-85, 85, (200, 3))
        r = euler_to_matrix(a, order)
        np.testing.assert_allclose(matrix_to_euler(r, order), a, atol=1e-9)
        lock = euler_to_matrix(np.array([[20.0, 90.0, 35.0]]), order)
        np.testing.assert_allclose(euler_to_matrix(matrix_to_euler(lock, order), order), lock, atol=1e-9)


def test_write_bvh_roundtrip(tmp_path, clips):
    src = clips["cmu_07_01_walk.bvh"]
    F = 20
    grot, gpos = src.global_rotations_positions(np.arange(F))
    lrot = src.local_rotations(np.arange(F))
    angles = matrix_to_euler(lrot, "ZXY")  # other order than the source on purpose
    out = tmp_path / "sub" / "rt.bvh"
    write_bvh(out, src.joint_names, src.parents, src.offsets, gpos[:, 0], angles,
              order="ZXY", frame_time=1 / 120, scale=0.01)
    assert not [p for p in out.parent.iterdir() if p.name != "rt.bvh"]  # no temp file left
    back = read_bvh(out, scale=0.01)
    assert back.joint_names == src.joint_names and back.n_frames == F
    assert back.fps == pytest.approx(120, rel=1e-4)
    np.testing.assert_allclose(back.global_positions(), gpos, atol=2e-6)
    # leaves got an End Site each
    leaves = set(range(src.n_joints)) - set(src.parents.tolist())
    assert {e[0] for e in back.end_sites} == leaves


def test_write_bvh_reorders_non_dfs_joints(tmp_path):
    names = ["r", "a", "b", "a2"]
    parents = [-1, 0, 0, 1]
    offsets = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0.0]])
    rot = np.zeros((2, 4, 3))
    rot[1, 1] = [90, 0, 0]  # a: Z 90
    out = tmp_path / "x.bvh"
    write_bvh(out, names, parents, offsets, np.zeros((2, 3)), rot, scale=1.0)
    back = read_bvh(out, scale=1.0)
    assert back.joint_names == ["r", "a", "a2", "b"]
    g = back.global_positions()
    np.testing.assert_allclose(g[1, back.index("a2")], [-1, 1, 0], atol=1e-6)
    np.testing.assert_allclose(g[1, back.index("b")], [1, 0, 0], atol=1e-6)


# ---------------------------------------------------------------- errors

GOOD = HAND.format(rot="Zrotation Yrotation Xrotation", angles="10 20 30")


def _err(tmp_path, text) -> BVHError:
    p = tmp_path / "bad.bvh"
    p.write_text(text)
    with pytest.raises(BVHError) as ei:
        read_bvh(p)
    assert str(p) in str(ei.value)
    return ei.value


def test_good_file_parses(tmp_path):
    p = tmp_path / "good.bvh"
    p.write_text(GOOD)
    assert read_bvh(p).n_frames == 1


def test_error_truncated(tmp_path):
    e = _err(tmp_path, GOOD.replace("Frames: 1", "Frames: 3"))
    assert "truncated" in e.message and e.line is not None
    short = GOOD.rstrip("\n").rsplit(" ", 2)[0] + "\n"  # last row lacks values
    e = _err(tmp_path, short)
    assert e.line == 19 and "values" in e.message
    e = _err(tmp_path, GOOD.split("MOTION")[0])
    assert "MOTION" in e.message


def test_error_channel_count(tmp_path):
    e = _err(tmp_path, GOOD.replace("CHANNELS 3", "CHANNELS 4"))
    assert e.line == 9 and "CHANNELS" in e.message


def test_error_unknown_rotation_order(tmp_path):
    e = _err(tmp_path, GOOD.replace("CHANNELS 3 Zrotation Yrotation Xrotation",
                                    "CHANNELS 3 Zrotation Zrotation Xrotation"))
    assert e.line == 9 and "rotation order" in e.message
    e = _err(tmp_path, GOOD.replace("CHANNELS 3 Zrotation", "CHANNELS 3 Wrotation"))
    assert e.line == 9 and "Wrotation" in e.message


def test_error_non_numeric(tmp_path):
    e = _err(tmp_path, GOOD.replace("1 2 3 10 20 30", "1 2 3 10 abc 30"))
    assert e.line == 19 and "abc" in e.message
    e = _err(tmp_path, GOOD.replace("OFFSET 0 1 0", "OFFSET 0 x 0"))
    assert e.line == 8


def test_error_structure(tmp_path):
    e = _err(tmp_path, GOOD.replace("HIERARCHY", "HIERARCHX"))
    assert "HIERARCHY" in e.message
    lines = GOOD.splitlines()
    e = _err(tmp_path, "\n".join(lines[:13] + lines[14:]) + "\n")  # drop a '}'
    assert "brace" in e.message and e.line is not None
    e = _err(tmp_path, GOOD.replace("Frame Time: 0.04", "Frame Time: zero"))
    assert e.line == 18
