"""The built-in samples (procedural body, items, motions): synthetic, no shared data."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from wearfit_usd.demo.samples import (
    CLEARANCE,
    GARMENT_SETS,
    PRESETS,
    REMESHED_TARGETS,
    SAME_TOPOLOGY_TARGETS,
    make_body,
    make_items,
    make_outfit,
    make_target,
    write_sample_set,
)
from wearfit_usd.demo.samples.body import JOINT_NAMES, layout
from wearfit_usd.geometry.closest import signed_distance
from wearfit_usd.motion.skinning import skin_mesh
from wearfit_usd.transforms import make_matrix, matrix_from_quat

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ref():
    return make_body("reference")


@pytest.fixture(scope="module")
def targets(ref):
    return {n: make_target(n, ref) for n in SAME_TOPOLOGY_TARGETS + list(REMESHED_TARGETS)}


@pytest.fixture(scope="module")
def items(ref):
    return {m.name: m for m in make_items(ref)}


def _tm(mesh):
    return trimesh.Trimesh(mesh.points, mesh.faces, process=False)


def _check_body_mesh(mesh):
    tm = _tm(mesh)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.euler_number == 2  # a sphere-like closed surface, no handles
    assert tm.volume > 0.03  # outward wound (and a human-sized volume, m^3)
    assert np.all(mesh.face_vertex_counts == 4)
    ang = np.degrees(tm.face_adjacency_angles)
    assert np.percentile(ang, 99) < 50.0 and ang.max() < 120.0  # smooth, no fold-overs
    assert tm.area_faces.min() > 1e-7  # no degenerate slivers
    assert tm.edges_unique_length.min() > 5e-4


def test_reference_body_is_a_clean_closed_surface(ref):
    m = ref.body
    assert 5000 <= m.n_points <= 15000
    _check_body_mesh(m)
    lo, hi = m.points.min(0), m.points.max(0)
    assert abs(hi[1] - 1.75) < 0.01 and abs(lo[1]) < 0.01  # 1.75 m, soles on the floor
    assert abs(hi[0] + lo[0]) < 0.01  # left/right symmetric
    assert ref.skeleton.joint_names == JOINT_NAMES


def test_skin_weights_and_bind_pose(ref):
    m, sk = ref.body, ref.skeleton
    assert m.joint_weights.shape[1] == 4
    assert np.allclose(m.joint_weights.sum(1), 1.0) and m.joint_weights.min() >= 0
    assert np.allclose(skin_mesh(m, sk, sk.bind_world), m.points, atol=1e-9)
    assert np.allclose(sk.world_from_local(sk.rest_local), sk.bind_world, atol=1e-9)
    # every weighted joint except Root has vertices
    dominant = set(np.asarray(JOINT_NAMES)[m.joint_indices[:, 0]])
    assert dominant == set(JOINT_NAMES) - {"Root"}


def test_bending_the_elbow_moves_the_hand_not_the_feet(ref):
    m, sk = ref.body, ref.skeleton
    local = sk.rest_local.copy()
    j = sk.index("lowerarm_l")
    q = np.array([np.cos(np.radians(45)), 0, 0, np.sin(np.radians(45))])  # 90 deg about z
    local[j] = make_matrix(rotation=matrix_from_quat(q)) @ local[j]
    posed = skin_mesh(m, sk, sk.world_from_local(local))
    moved = np.linalg.norm(posed - m.points, axis=1)
    dom = np.asarray(JOINT_NAMES)[m.joint_indices[:, 0]]
    assert moved[dom == "hand_l"].min() > 0.1
    assert moved[np.isin(dom, ["foot_l", "foot_r", "ball_l", "calf_r", "hand_r"])].max() < 1e-9
    # the elbow blends: some vertices move partially (no hard seam)
    near = np.linalg.norm(m.points - sk.bind_world[j, 3, :3], axis=1) < 0.05
    assert np.any((moved[near] > 0.002) & (moved[near] < 0.03))
    assert _tm(m.copy_with_points(posed)).is_watertight


def test_presets_differ_by_their_parameters(ref, targets):
    for name, t in targets.items():
        p = PRESETS[name]
        assert abs(t.body.points[:, 1].max() - p.height) < 0.012, name
        _check_body_mesh(t.body)
        assert np.allclose(skin_mesh(t.body, t.skeleton, t.skeleton.bind_world), t.body.points)

    def waist_depth(c):
        y = layout(PRESETS["reference"]).landmarks["waist_y"] * c.body.points[:, 1].max() / 1.75
        dom = np.asarray(JOINT_NAMES)[c.body.joint_indices[:, 0]]
        sl = (np.abs(c.body.points[:, 1] - y) < 0.02) & np.isin(dom, ["spine_01", "pelvis", "spine_02"])
        return np.ptp(c.body.points[sl, 2])

    d0 = waist_depth(ref)
    # thin: girth 0.82 x height 1.92/1.75 -> about 0.90 of the reference
    assert 0.82 < waist_depth(targets["tall_thin"]) / d0 < 0.97
    # heavy with a belly: much deeper waist despite being shorter
    assert waist_depth(targets["short_heavy"]) / d0 > 1.3
    # broad shoulders: shoulder joint x = (0.17 shoulders + 0.15 (girth - 1)) height / 1.75
    def shoulder(c):
        sk = c.skeleton
        return sk.bind_world[sk.index("upperarm_l"), 3, 0] - sk.bind_world[sk.index("upperarm_r"), 3, 0]
    r = shoulder(targets["broad_shoulders"]) / shoulder(ref)
    assert abs(r - (0.17 * 1.25 + 0.15 * 0.08) / 0.17 * 1.80 / 1.75) < 0.005
    assert r > 1.3
    vols = {n: _tm(t.body).volume for n, t in targets.items()}
    assert vols["short_heavy"] > 1.2 * _tm(ref.body).volume > 1.2 * vols["tall_thin"]


def test_same_topology_and_remeshed_targets(ref, targets):
    for name in SAME_TOPOLOGY_TARGETS:
        t = targets[name].body
        assert t.n_points == ref.body.n_points
        assert np.array_equal(t.face_vertex_indices, ref.body.face_vertex_indices)
        assert np.array_equal(t.faces, ref.body.faces)
        assert not np.allclose(t.points, ref.body.points, atol=0.01)
    for name in REMESHED_TARGETS:
        t = targets[name].body
        assert 5000 <= t.n_points <= 15000
        assert abs(t.n_points - ref.body.n_points) > 1000  # a different topology


def test_items_are_outside_the_body_with_their_clearance(ref, items):
    b = ref.body
    assert set(items) == set(CLEARANCE)
    for name, m in items.items():
        sd = signed_distance(b.points, b.faces, m.points)
        assert sd.min() > 0.8 * CLEARANCE[name], (name, sd.min())
        assert any(pv.name == "st" and pv.type_name == "texCoord2f[]" for pv in m.primvars), name
        assert m.display_color is not None
        assert m.faces.max() < m.n_points and len(np.unique(m.faces)) == m.n_points, name
        assert _tm(m).is_winding_consistent, name
        assert np.mean(m.face_vertex_counts == 4) > 0.8, name  # quads where natural


def test_outfit_layers_keep_their_order(ref, items):
    from scipy.spatial import cKDTree
    b = ref.body
    inner, outer = items["undershirt"], items["shirt"]
    sd_in = signed_distance(b.points, b.faces, inner.points)
    sd_out = signed_distance(b.points, b.faces, outer.points)
    d, k = cKDTree(outer.points).query(inner.points)
    overlap = d < 0.02
    assert overlap.mean() > 0.8  # the shirt covers the undershirt
    assert np.all(sd_out[k[overlap]] > sd_in[overlap] + 0.004)


def test_item_shapes(ref, items):
    lay = layout(PRESETS["reference"])
    L, J = lay.landmarks, lay.joints
    # skirt: one convex-ish tube around both legs, not two legs
    sk = items["skirt"].points
    bottom = sk[sk[:, 1] < sk[:, 1].min() + 0.005]
    from scipy.spatial import ConvexHull
    assert len(bottom) >= 48
    xz = bottom[:, [0, 2]] - bottom[:, [0, 2]].mean(0)
    xz = xz[np.argsort(np.arctan2(xz[:, 0], xz[:, 1]))]
    area = 0.5 * abs(np.sum(xz[:, 0] * np.roll(xz[:, 1], -1) - np.roll(xz[:, 0], -1) * xz[:, 1]))
    assert area > 0.99 * ConvexHull(xz).volume  # convex ring: does not wrap each leg
    ctr = bottom[np.argmin(np.abs(bottom[:, 0]))]  # front/back point between the legs
    assert signed_distance(ref.body.points, ref.body.faces, ctr[None])[0] > 0.05
    # hat: above the head, brim wider than the head
    hat = items["hat"].points
    assert hat[:, 1].max() > 1.75 and np.ptp(hat[:, 0]) > 2 * L["head_radii"][0] + 0.08
    # glasses in front of the eyes, centred
    g = items["glasses"].points
    front = g[g[:, 2] > L["eye_l"][2]]
    assert len(front) > 0.4 * len(g) and abs(g[:, 0].mean()) < 0.005
    # watch around the left wrist, necklace around the neck
    w = items["watch"].points.mean(0)
    assert np.linalg.norm(w - J["hand_l"]) < 0.06
    n = items["necklace"].points
    assert abs(n[:, 0].mean()) < 0.005 and np.all(n[:, 1] > L["chest_y"] - 0.05)
    # trousers: two legs below the crotch (the gap between the legs is open)
    tr = items["trousers"].points
    knee = tr[np.abs(tr[:, 1] - L["knee_y"]) < 0.02]
    assert np.all(np.abs(knee[:, 0]) > 0.02)
    # shoes: two of them, on the feet
    sh = items["shoes"].points
    assert sh[:, 1].max() < 0.15 and (sh[:, 0] > 0).any() and (sh[:, 0] < 0).any()


@pytest.mark.slow  # writes and re-reads the whole sample set (5 s)
def test_sample_set_round_trips_through_usd(tmp_path):
    from wearfit_usd.io.usd import read_character
    paths = write_sample_set(tmp_path, targets=["tall_thin", "curvy_remeshed"])
    assert set(paths) == {"reference", "target_tall_thin", "target_curvy_remeshed"} | set(GARMENT_SETS)
    ref = make_body("reference")
    ref_items = {m.name: m for m in make_items(ref)}
    _same_items(read_character(paths["ref_loose"]), make_outfit(ref, "ref_loose"))
    back = read_character(paths["reference"])
    assert np.abs(back.body.points - ref.body.points).max() < 1e-5
    assert np.array_equal(back.body.face_vertex_indices, ref.body.face_vertex_indices)
    assert back.skeleton.joint_names == JOINT_NAMES
    assert np.allclose(back.skeleton.bind_world, ref.skeleton.bind_world, atol=1e-6)
    assert np.allclose(skin_mesh(back.body, back.skeleton, back.skeleton.bind_world),
                       back.body.points, atol=1e-5)
    assert {m.name for m in back.items} == set(ref_items)
    _same_items(back, ref_items.values())
    for key in ("target_tall_thin", "target_curvy_remeshed"):
        t = read_character(paths[key])
        assert t.items == [] and t.skeleton is not None
    t = read_character(paths["target_tall_thin"])
    assert np.array_equal(t.body.face_vertex_indices, ref.body.face_vertex_indices)
    only = write_sample_set(tmp_path / "few", targets=[], garment_sets=["ref_suit"])
    assert set(only) == {"reference", "ref_suit"}


def _same_items(back, items):
    """The items read back from a stage equal the ones written."""
    src_items = {m.name: m for m in items}
    assert [m.name for m in back.items] == list(src_items)
    for m in back.items:
        src = src_items[m.name]
        assert np.abs(m.points - src.points).max() < 1e-5, m.name
        assert np.array_equal(m.face_vertex_counts, src.face_vertex_counts)
        assert np.array_equal(m.face_vertex_indices, src.face_vertex_indices)
        st = next(pv for pv in m.primvars if pv.name == "st")
        st0 = src.primvars[0]
        assert st.interpolation == st0.interpolation
        assert np.allclose(st.values, st0.values, atol=1e-6)
        assert (st.indices is None) == (st0.indices is None)
        if st0.indices is not None:
            assert np.array_equal(st.indices, st0.indices)
        assert np.allclose(m.display_color, src.display_color, atol=1e-6)


# --------------------------------------------------------------------------
# motions

@pytest.fixture(scope="module")
def clips():
    from wearfit_usd.io.bvh import read_bvh
    return {n: read_bvh(REPO / "motions" / f"{n}.bvh") for n in ("walk", "arm_raise", "squat", "look")}


def test_clips_are_committed_deterministic_and_packaged(tmp_path):
    from wearfit_usd.demo.samples import motion_path
    from wearfit_usd.demo.samples.motions import CLIPS, write_clips
    write_clips([tmp_path])
    for n in CLIPS:
        fresh = (tmp_path / f"{n}.bvh").read_bytes()
        assert (REPO / "motions" / f"{n}.bvh").read_bytes() == fresh
        assert motion_path(n).read_bytes() == fresh
        assert motion_path(n).parent.name == "motions" and "wearfit_usd" in str(motion_path(n))


def test_clip_headers(clips):
    for n, m in clips.items():
        assert m.n_frames if hasattr(m, "n_frames") else True
        s = m.summary()
        assert s["frames"] == 60 and abs(s["fps"] - 30.0) < 1e-6, n
        assert s["units"] == "cm" and s["up_axis"] == "Y", n
        assert s["rotation_orders"] == {"ZYX": 21}, n
        assert 1.4 < s["height_m"] < 1.7


def test_walk_alternates_feet_and_advances(clips):
    m = clips["walk"]
    g = m.global_positions()
    lf, rf, hips = g[:, m.index("LeftFoot")], g[:, m.index("RightFoot")], g[:, m.index("Hips")]
    lead = np.sign(lf[:, 2] - rf[:, 2])
    assert np.count_nonzero(np.diff(lead[lead != 0]) != 0) >= 3  # left, right, left, right
    assert np.ptp(lf[:, 2] - rf[:, 2]) > 0.5
    assert hips[-1, 2] - hips[0, 2] > 1.5  # about 1.1 m/s for 2 s
    low = np.minimum(lf[:, 1], rf[:, 1])
    assert np.all(np.abs(low - 0.08) < 0.01)  # one ankle on the floor every frame
    assert lf[:, 1].max() > 0.15 and rf[:, 1].max() > 0.15  # the swing foot lifts


def test_arm_raise_goes_above_the_head(clips):
    m = clips["arm_raise"]
    g = m.global_positions()
    head = g[:, m.index("Head"), 1]
    for side in ("Left", "Right"):
        hand = g[:, m.index(f"{side}Hand"), 1]
        assert hand[0] < 1.0 and hand[-1] < 1.0  # starts and ends down
        assert hand.max() > head.max() + 0.2  # above the head in the middle
        assert np.argmax(hand) in range(25, 35)


def test_look_turns_and_nods_the_head_standing_still(clips):
    """The chest twists (the shoulders' line turns over 20 degrees), the head
    nods down and up (the neck-to-head segment tips over 8 degrees each way),
    the feet stay put, and the clip ends in the pose it starts in."""
    m = clips["look"]
    g = m.global_positions()
    shoulders = g[:, m.index("LeftShoulder")] - g[:, m.index("RightShoulder")]
    up = g[:, m.index("Head")] - g[:, m.index("Neck")]
    assert np.ptp(np.degrees(np.arctan2(shoulders[:, 2], shoulders[:, 0]))) > 20  # the chest twists
    pitch = np.degrees(np.arctan2(up[:, 2], up[:, 1]))
    assert pitch.max() - pitch[0] > 8 and pitch[0] - pitch.min() > 8  # nods down and up
    for foot in ("LeftFoot", "RightFoot"):
        assert np.ptp(g[:, m.index(foot)], axis=0).max() < 0.03
    np.testing.assert_allclose(g[0], g[-1], atol=1e-3)


def test_squat_bends_with_feet_on_the_floor(clips):
    m = clips["squat"]
    g = m.global_positions()
    hips = g[:, m.index("Hips"), 1]
    assert hips[0] - hips.min() > 0.3
    for side in ("Left", "Right"):
        ank = g[:, m.index(f"{side}Foot")]
        assert np.ptp(ank[:, 1]) < 0.005 and np.ptp(ank[:, 2]) < 0.01
