"""Skirt parts' skin weights carried from the hips to the legs
(dress/skirt_weights.py): known answers on synthetic cases, the hips' frame
and the legs' skin on the data set's rigs, and the skinned long skirt in a walk."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from tests.conftest import BVH_DIR, USD_DIR
from wearfit_usd.dress.item_weights import weight_matrix
from wearfit_usd.dress.regions import LEFT_LEG, RIGHT_LEG, TORSO, joint_regions, vertex_regions, weight_region_shares
from wearfit_usd.dress.skirt_weights import Hips, LegSkin, has_leg_skin, hip_axes, skirt_weights
from wearfit_usd.model import Skeleton

# hip joints at x = +-0.1 (joints 1 and 2), the thighs straight down: u = x
# / 0.2, depth s = -y; joint 3 is below the left knee, 4 below the right
J = 5  # 0 pelvis, 1 left thigh, 2 right thigh, 3 left calf, 4 right calf
HIPS = Hips(np.zeros(3), np.array([0.2, 0.0, 0.0]), np.array([0.0, -1.0, 0.0]), np.array([1, 2]),
            np.array([[False, False, False, True, False], [False, False, False, False, True]]))


def _onehot(rows, j):
    w = np.zeros((rows, J))
    w[:, j] = 1.0
    return w


def _near(n):
    return np.zeros(n), np.zeros(n)


def test_skirt_weights_known_answers_near_the_legs():
    # cloth on the skin: over the left hip joint and beyond, the left side's
    # skin; on the midline half each; a quarter of the way out at gain 1 (an
    # eighth at gain 2): smoothstep(0.75) = 0.84375 of the left's
    p = np.array([[0.1, -0.5, 0.1],      # over the left hip joint
                  [0.3, 0.1, 0.1],       # beyond it, above the hips
                  [0.0, -0.5, 0.1],      # midline
                  [0.05, -0.5, -0.1],    # u = 1/4
                  [-0.1, -0.5, 0.1]])    # over the right hip joint
    n = len(p)
    sides = (_onehot(n, 1), _onehot(n, 2))
    w = skirt_weights(_onehot(n, 0), p, HIPS, sides, _near(n), side_gain=1.0)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    np.testing.assert_allclose(w[0], [0, 1, 0, 0, 0])
    np.testing.assert_allclose(w[1], [0, 1, 0, 0, 0])
    np.testing.assert_allclose(w[2], [0, 0.5, 0.5, 0, 0])
    np.testing.assert_allclose(w[3], [0, 0.84375, 0.15625, 0, 0])
    np.testing.assert_allclose(w[4], [0, 0, 1, 0, 0])
    # gain 2 (the default): wholly on the left from u = 1/4 out
    w2 = skirt_weights(_onehot(n, 0), p, HIPS, sides, _near(n))
    np.testing.assert_allclose(w2[3], [0, 1, 0, 0, 0])
    np.testing.assert_allclose(w2[2], [0, 0.5, 0.5, 0, 0])
    w3 = skirt_weights(_onehot(1, 0), np.array([[0.025, -0.5, 0.1]]), HIPS, (_onehot(1, 1), _onehot(1, 2)), _near(1))
    np.testing.assert_allclose(w3[0], [0, 0.84375, 0.15625, 0, 0])


def test_cloth_the_legs_swing_cannot_reach_follows_the_thigh_and_half_the_hips():
    # 0.8 m below the hip joints a leg swings 0.4 m (REACH 0.5): cloth up to
    # 0.2 x 0.4 = 8 cm from the skin follows it as it is (calf included),
    # from 0.5 x 0.4 = 20 cm on the calf's weight goes to the thigh and half
    # of all to the hips; at 14 cm (halfway) smoothstep(0.5) = 1/2 of each.
    # Near the hips the swing is at least SWING_MIN 0.15 m: 3 cm is near
    p = np.array([[0.1, -0.8, 0.1]] * 4 + [[0.1, -0.05, 0.1]])
    skin = np.array([[0.0, 0.4, 0.0, 0.6, 0.0]] * 5)   # thigh 0.4, calf 0.6
    d = np.array([0.05, 0.30, 0.14, 0.08, 0.03])
    w = skirt_weights(_onehot(5, 0), p, HIPS, (skin, _onehot(5, 2)), (d, np.ones(5)))
    np.testing.assert_allclose(w[0], skin[0])
    np.testing.assert_allclose(w[3], skin[0])             # at the edge of "near"
    np.testing.assert_allclose(w[1], [0.5, 0.5, 0, 0, 0])  # far: thigh alone, half the hips
    # halfway: the calf's 0.6 half to the thigh (0.7, 0.3), then a quarter to the hips
    np.testing.assert_allclose(w[2], [0.25, 0.75 * 0.7, 0, 0.75 * 0.3, 0])
    np.testing.assert_allclose(w[4], skin[0])
    np.testing.assert_allclose(w.sum(axis=1), 1.0)


def test_skirt_weights_blend_the_sides_skin_not_a_joint():
    # the sides' weights are whatever the skin under the vertex has: they
    # come through as given, scaled by the side's part
    p = np.array([[0.1, -0.8, 0.1], [0.0, -0.8, 0.1]])   # over the left hip joint; the middle
    wl = np.array([[0.0, 0.3, 0.0, 0.7, 0.0]] * 2)
    wr = np.array([[0.0, 0.0, 0.4, 0.0, 0.6]] * 2)
    w = skirt_weights(_onehot(2, 0), p, HIPS, (wl, wr), _near(2))
    np.testing.assert_allclose(w[0], wl[0])
    np.testing.assert_allclose(w[1], 0.5 * wl[1] + 0.5 * wr[1])


def test_skirt_weights_reject_bad_input():
    p = np.zeros((3, 3))
    sides = (_onehot(3, 1), _onehot(3, 2))
    with pytest.raises(ValueError, match="expected"):
        skirt_weights(_onehot(3, 0), p[:2], HIPS, sides, _near(3))
    with pytest.raises(ValueError, match="expected"):
        skirt_weights(_onehot(3, 0), p, HIPS, (_onehot(3, 1), _onehot(2, 2)), _near(3))
    with pytest.raises(ValueError, match="expected"):
        skirt_weights(_onehot(3, 0), p, HIPS, sides, _near(2))
    with pytest.raises(ValueError, match="side_gain"):
        skirt_weights(_onehot(3, 0), p, HIPS, sides, _near(3), side_gain=0.0)
    with pytest.raises(ValueError, match="far"):
        skirt_weights(_onehot(3, 0), p, HIPS, sides, _near(3), far=(0.5, 0.2))


@pytest.mark.parametrize("body, left, right, knees", [
    ("ref_female.usda", "thigh_l", "thigh_r", ("calf_l", "calf_r")),
    ("body_male_cmu_rig.usdc", "LeftUpLeg", "RightUpLeg", ("LeftLeg", "RightLeg")),
    ("body_male_muscular_posed.usdc", "thigh_l", "thigh_r", ("calf_l", "calf_r"))])
def test_hip_axes_are_the_thighs_roots_whatever_their_names(body, left, right, knees):
    from wearfit_usd.io.usd import read_character
    sk = read_character(USD_DIR / body).skeleton
    pos = sk.bind_positions()
    for s in (sk, _renamed(sk)):
        h = hip_axes(s)
        np.testing.assert_allclose(h.middle + 0.5 * h.lateral, pos[sk.index(left)], atol=1e-9)
        np.testing.assert_allclose(h.middle - 0.5 * h.lateral, pos[sk.index(right)], atol=1e-9)
        assert [sk.joint_names[j] for j in h.thighs] == [left, right]
        assert abs(np.linalg.norm(h.down) - 1.0) < 1e-9 and h.down[1] < -0.8  # down the thighs
        # below each knee: the knee, the foot and the toes, not the thigh
        for side, (thigh, knee) in enumerate(zip(h.thighs, knees)):
            below = {sk.joint_names[j] for j in np.flatnonzero(h.below_knee[side])}
            assert knee in below and sk.joint_names[thigh] not in below and len(below) >= 3, below
            assert np.all(pos[h.below_knee[side], 1] < pos[thigh, 1])


def _renamed(sk):
    s = copy.deepcopy(sk)
    s.joint_names = [f"j{i:03d}" for i in range(s.n_joints)]
    s.joint_paths = list(s.joint_names)
    return s


def test_a_skeleton_without_legs_has_no_hip_axes():
    # a spine and a head only: no leg subtrees
    n = 6
    local = np.tile(np.eye(4), (n, 1, 1))
    local[1:, 3, 1] = 0.2
    world = np.cumsum(local[:, 3, :3], axis=0)
    bind = np.tile(np.eye(4), (n, 1, 1))
    bind[:, 3, :3] = world
    s = Skeleton([f"s{i}" for i in range(n)], [f"s{i}" for i in range(n)], np.arange(-1, n - 1), bind, local)
    assert hip_axes(s) is None


def test_leg_skin_reads_each_sides_skin(ref_female):
    # a point in front of the left knee takes the left leg's skin, the right
    # side's query in front of the right knee the right leg's; a point by the
    # left hip the torso's and the thigh's, never the other leg's
    body, sk = ref_female.body, ref_female.skeleton
    bw = weight_matrix(body.joint_indices, body.joint_weights, sk.n_joints)
    labels = vertex_regions(body, sk)
    legs = LegSkin(body.points, body.faces, bw, labels)
    knee = sk.bind_positions()[[sk.index("calf_l"), sk.index("calf_r")]]
    q = knee + np.array([0.0, 0.0, 0.15])   # in front of each knee
    (wl, wr), (dl, dr) = legs.weights(q)
    assert 0.05 < dl[0] < 0.15 and 0.05 < dr[1] < 0.15   # 15 cm in front of the joint, the knee's skin
    jl = joint_regions(sk)
    np.testing.assert_allclose(wl.sum(axis=1), 1.0)
    assert wl[0][jl == LEFT_LEG].sum() > 0.99 and wr[1][jl == RIGHT_LEG].sum() > 0.99
    # the calf and thigh both: the knee's skin bends with both
    assert wl[0][sk.index("calf_l")] > 0.2 and wl[0][sk.index("thigh_l")] > 0.2
    hip = sk.bind_positions()[sk.index("thigh_l")] + np.array([0.08, 0.05, 0.0])
    (wh, _), _ = legs.weights(hip[None])
    assert wh[0][jl == RIGHT_LEG].sum() == 0.0 and wh[0][(jl == TORSO) | (jl == LEFT_LEG)].sum() > 0.99
    assert wh[0][sk.index("pelvis")] > 0.3 and wh[0][sk.index("thigh_l")] > 0.3   # the hip's skin: both
    with pytest.raises(ValueError, match="vertices"):
        LegSkin(body.points[:-1], body.faces, bw, labels)
    # a body whose skin holds no leg (every weight on the pelvis): no LegSkin,
    # and skinned_items keeps the skirt on its binding's weights
    pi, pw = np.full((body.n_points, 1), sk.index("pelvis")), np.ones((body.n_points, 1))
    pelvis, pelvis_labels = weight_matrix(pi, pw, sk.n_joints), np.argmax(weight_region_shares(pi, pw, sk), axis=1)
    assert has_leg_skin(labels) and not has_leg_skin(pelvis_labels)
    with pytest.raises(ValueError, match="leg"):
        LegSkin(body.points, body.faces, pelvis, pelvis_labels)


@pytest.mark.slow
def test_the_skinned_long_skirt_keeps_the_legs_inside_in_a_walk(tmp_path):
    """ref_female_longskirt on body_female_heavy, CMU walk's first 15 frames
    at 30 fps: the skirt's skinned copy (LBS of its weights, as UsdSkel and
    engines pose it) against the per-frame redress (issue 19: within 1
    percentage point). On the hips' weights of its binding the legs came
    through it in every stride: 16.8 % new penetrations, 47.9 % of the body
    it covers uncovered (the redress: 0.14 / 2.3 %); now 0.70 / 0.40 %.
    These are the weights ``dress`` writes; ``animate`` puts skirts on
    joints of their own (``animate.item_joints``, its own tests), so the
    shot is made without them."""
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    ref = read_character(USD_DIR / "ref_female_longskirt.usda")
    tgt = read_character(USD_DIR / "body_female_heavy.usdc")
    walk = read_bvh(BVH_DIR / "cmu_07_01_walk.bvh")
    rep = animate(ref, tgt, walk, tmp_path / "walk.usdc",
                  AnimateOptions(start=1, end=61, items="both", measure_every=1, item_joints=False))
    sk, rd = rep.motion_worst["long_skirt_skinned"], rep.motion_worst["long_skirt"]
    assert rep.frames == 15
    assert rd["new_pen_pct"]["value"] < 1.0
    assert sk["new_pen_pct"]["value"] <= rd["new_pen_pct"]["value"] + 1.0, (sk["new_pen_pct"], rd["new_pen_pct"])
    assert sk["coverage_loss_pct"]["value"] < 2.0, sk["coverage_loss_pct"]


@pytest.mark.slow
def test_a_wide_dress_skinned_keeps_its_shape_and_the_legs_inside(tmp_path):
    """The demo's A-line dress (``ref_loose``) on its ``tall_thin`` sample in
    the package's walk: its skinned copy within 1 point of the redress's new
    penetrations, and its hem not flung about: cloth the legs' swing cannot
    reach follows the thigh, not the knee's bend, and half the hips. With
    every skirt vertex on the skin under it (calf included) the copy had 0 %
    new penetrations but edges stretched 4.6x at p99 (the hem swung out with
    the calves, creased at the knees); now 0.25 % and 2.44x (the redress
    0.08 %, 1.1x)."""
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.demo.samples import motion_path, write_sample_set
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    paths = write_sample_set(tmp_path / "samples", targets=["tall_thin"])
    ref, tgt = read_character(paths["ref_loose"]), read_character(paths["target_tall_thin"])
    walk = read_bvh(motion_path("walk"))
    rep = animate(ref, tgt, walk, tmp_path / "walk.usdc",
                  AnimateOptions(start=1, end=60, items="both", measure_every=2, item_joints=False))
    sk, rd = rep.motion_worst["dress_skinned"], rep.motion_worst["dress"]
    assert sk["new_pen_pct"]["value"] <= rd["new_pen_pct"]["value"] + 1.0, (sk["new_pen_pct"], rd["new_pen_pct"])
    assert sk["stretch_p99"]["value"] < 3.5, sk["stretch_p99"]
