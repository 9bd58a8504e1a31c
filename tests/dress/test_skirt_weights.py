"""Skirt parts' skin weights carried from the hips to the legs
(dress/skirt_weights.py): known answers on synthetic cases, the hips' frame
and the legs' skin on the data set's rigs, and the skinned long skirt in a walk."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from tests.conftest import BVH_DIR, USD_DIR
from wearfit_usd.dress.item_weights import weight_matrix
from wearfit_usd.dress.regions import LEFT_LEG, RIGHT_LEG, TORSO, joint_regions
from wearfit_usd.dress.skirt_weights import LegSkin, hip_axes, skirt_weights
from wearfit_usd.model import Skeleton

# hips at x = +-0.1, the thighs straight down: u = x / 0.2, depth s = -y
AXES = (np.zeros(3), np.array([0.2, 0.0, 0.0]), np.array([0.0, -1.0, 0.0]))
J = 4  # 0 pelvis, 1 left leg, 2 right leg, 3 spine


def _onehot(rows, j):
    w = np.zeros((rows, J))
    w[:, j] = 1.0
    return w


def test_skirt_weights_known_answers():
    # on the hips (pelvis) above the ramp; far below it, over the left hip
    # joint and beyond: the left leg's skin; on the midline half each; a
    # quarter of the way out: smoothstep(0.75) = 0.84375 of the left's
    p = np.array([[0.0, 0.15, 0.1],      # above start (-0.10): hips' weights kept
                  [0.1, -0.5, 0.1],      # over the left hip joint, deep
                  [0.3, -0.5, 0.1],      # beyond it
                  [0.0, -0.5, 0.1],      # midline
                  [0.05, -0.5, 0.1],     # u = 1/4
                  [-0.1, -0.5, 0.1],     # over the right hip joint
                  [0.1, 0.025, 0.1]])    # halfway down the ramp: t = 1/2
    legs = (_onehot(len(p), 1), _onehot(len(p), 2))
    w = skirt_weights(_onehot(len(p), 0), p, AXES, legs, start=-0.1, ramp=0.15, side_gain=1.0)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    np.testing.assert_allclose(w[0], [1, 0, 0, 0])
    np.testing.assert_allclose(w[1], [0, 1, 0, 0])
    np.testing.assert_allclose(w[2], [0, 1, 0, 0])
    np.testing.assert_allclose(w[3], [0, 0.5, 0.5, 0])
    np.testing.assert_allclose(w[4], [0, 0.84375, 0.15625, 0])
    np.testing.assert_allclose(w[5], [0, 0, 1, 0])
    np.testing.assert_allclose(w[6], [0.5, 0.5, 0, 0])
    # gain 2: wholly on the left from u = 1/4 out; u = 1/8 gives smoothstep(0.75)
    w2 = skirt_weights(_onehot(len(p), 0), p, AXES, legs, start=-0.1, ramp=0.15, side_gain=2.0)
    np.testing.assert_allclose(w2[4], [0, 1, 0, 0])
    np.testing.assert_allclose(w2[3], [0, 0.5, 0.5, 0])
    q = np.array([[0.025, -0.5, 0.1]])
    w3 = skirt_weights(_onehot(1, 0), q, AXES, (_onehot(1, 1), _onehot(1, 2)), side_gain=2.0)
    np.testing.assert_allclose(w3[0], [0, 0.84375, 0.15625, 0])


def test_skirt_weights_blend_the_legs_skin_not_a_joint():
    # the legs' weights are whatever the skin under the vertex has (thigh and
    # calf here): they come through as given, scaled by the side's part
    p = np.array([[0.1, -0.8, 0.1], [0.0, -0.8, 0.1]])   # over the left hip joint; the middle
    wl = np.array([[0.0, 0.3, 0.0, 0.7]] * 2)   # "calf" 3 and "thigh" 1
    wr = np.array([[0.0, 0.0, 0.4, 0.6]] * 2)
    w = skirt_weights(_onehot(2, 0), p, AXES, (wl, wr))
    np.testing.assert_allclose(w[0], wl[0])
    np.testing.assert_allclose(w[1], 0.5 * wl[1] + 0.5 * wr[1])


def test_skirt_weights_reject_bad_input():
    p = np.zeros((3, 3))
    legs = (_onehot(3, 1), _onehot(3, 2))
    with pytest.raises(ValueError, match="expected"):
        skirt_weights(_onehot(2, 0), p, AXES, legs)
    with pytest.raises(ValueError, match="expected"):
        skirt_weights(_onehot(3, 0), p, AXES, (_onehot(3, 1), _onehot(2, 2)))
    with pytest.raises(ValueError, match="ramp"):
        skirt_weights(_onehot(3, 0), p, AXES, legs, ramp=0.0)


@pytest.mark.parametrize("body, left, right", [("ref_female.usda", "thigh_l", "thigh_r"),
                                               ("body_male_cmu_rig.usdc", "LeftUpLeg", "RightUpLeg"),
                                               ("body_male_muscular_posed.usdc", "thigh_l", "thigh_r")])
def test_hip_axes_are_the_thighs_roots_whatever_their_names(body, left, right):
    from wearfit_usd.io.usd import read_character
    sk = read_character(USD_DIR / body).skeleton
    pos = sk.bind_positions()
    for s in (sk, _renamed(sk)):
        mid, lateral, down = hip_axes(s)
        np.testing.assert_allclose(mid + 0.5 * lateral, pos[sk.index(left)], atol=1e-9)
        np.testing.assert_allclose(mid - 0.5 * lateral, pos[sk.index(right)], atol=1e-9)
        assert abs(np.linalg.norm(down) - 1.0) < 1e-9 and down[1] < -0.8  # down the thighs


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
    legs = LegSkin(body.points, body.faces, bw, sk)
    knee = sk.bind_positions()[[sk.index("calf_l"), sk.index("calf_r")]]
    q = knee + np.array([0.0, 0.0, 0.15])   # in front of each knee
    wl, wr = legs.weights(q)
    jl = joint_regions(sk)
    np.testing.assert_allclose(wl.sum(axis=1), 1.0)
    assert wl[0][jl == LEFT_LEG].sum() > 0.99 and wr[1][jl == RIGHT_LEG].sum() > 0.99
    # the calf and thigh both: the knee's skin bends with both
    assert wl[0][sk.index("calf_l")] > 0.2 and wl[0][sk.index("thigh_l")] > 0.2
    hip = sk.bind_positions()[sk.index("thigh_l")] + np.array([0.08, 0.05, 0.0])
    wh, _ = legs.weights(hip[None])
    assert wh[0][jl == RIGHT_LEG].sum() == 0.0 and wh[0][(jl == TORSO) | (jl == LEFT_LEG)].sum() > 0.99
    assert wh[0][sk.index("pelvis")] > 0.3 and wh[0][sk.index("thigh_l")] > 0.3   # the hip's skin: both
    with pytest.raises(ValueError, match="vertices"):
        LegSkin(body.points[:-1], body.faces, bw, sk)


@pytest.mark.slow
def test_the_skinned_long_skirt_keeps_the_legs_inside_in_a_walk(tmp_path):
    """ref_female_longskirt on body_female_heavy, CMU walk's first 15 frames
    at 30 fps: the skirt's skinned copy (LBS of its weights, as UsdSkel and
    engines pose it). Bound to the hips alone the legs came through it in
    every stride: 16.8 % new penetrations, 47.9 % of the body it covers
    uncovered (the redress: 0.14 / 2.3 %); now 2.1 / 1.9 %."""
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    ref = read_character(USD_DIR / "ref_female_longskirt.usda")
    tgt = read_character(USD_DIR / "body_female_heavy.usdc")
    walk = read_bvh(BVH_DIR / "cmu_07_01_walk.bvh")
    rep = animate(ref, tgt, walk, tmp_path / "walk.usdc", AnimateOptions(start=1, end=61, items="both", measure_every=1))
    sk, rd = rep.motion_worst["long_skirt_skinned"], rep.motion_worst["long_skirt"]
    assert rep.frames == 15
    assert sk["new_pen_pct"]["value"] < 4.0, sk["new_pen_pct"]
    assert sk["coverage_loss_pct"]["value"] < 4.0, sk["coverage_loss_pct"]
    assert rd["new_pen_pct"]["value"] < 1.0
