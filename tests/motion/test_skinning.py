"""Our numpy LBS equals UsdSkel's ComputeSkinnedPoints on every real body."""
from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import USD_DIR
from tests.usdskel_reference import author_animation, usdskel_skinned_points
from wearfit_usd.io.usd import open_stage, read_character
from wearfit_usd.motion.skinning import skin_mesh, skin_points
from wearfit_usd.transforms import make_matrix, matrix_from_quat, transform_points

BODIES = sorted(p.name for p in USD_DIR.glob("*.usd*"))


def random_pose(skel, rng, amount=0.6):
    """Rest pose with random joint rotations, a root offset and mild scales."""
    j = skel.n_joints
    q = np.concatenate([np.ones((j, 1)), rng.normal(scale=amount / 2, size=(j, 3))], axis=1)
    # scales are stored as half floats by SkelAnimation: use representable values
    scale = rng.uniform(0.9, 1.1, size=(j, 3)).astype(np.float16).astype(np.float64)
    rot = make_matrix(rotation=matrix_from_quat(q), scale=scale)
    local = rot @ skel.rest_local
    local[0, 3, :3] += rng.normal(scale=0.1, size=3)
    return local


@pytest.mark.parametrize("name", BODIES)
def test_lbs_matches_usdskel(name):
    path = USD_DIR / name
    char = read_character(path)
    skel = char.skeleton
    rng = np.random.default_rng(len(name))
    local = np.stack([skel.rest_local, random_pose(skel, rng), random_pose(skel, rng, 1.2)])
    stage = open_stage(path)
    author_animation(stage, skel.path, local, skel.joint_paths)
    ours = skin_mesh(char.body, skel, skel.world_from_local(local))
    for f in range(local.shape[0]):
        ref = transform_points(usdskel_skinned_points(stage, char.body.path, f), char.to_internal)
        scale = np.abs(ref).max()
        err = np.abs(ours[f] - ref).max() / scale
        assert err < 1e-5, f"{name} frame {f}: relative error {err:.2e}"
    # the posed frames really moved
    assert np.abs(ours[1] - ours[0]).max() > 0.05


def test_rest_pose_is_identity(ref_male):
    skel = ref_male.skeleton
    out = skin_mesh(ref_male.body, skel, skel.bind_world)
    np.testing.assert_allclose(out, ref_male.body.points, atol=1e-6)


def test_synthetic_two_joint_blend():
    """Hand-computed: a point weighted 50/50 between a fixed joint and one
    translated by (0, 2, 0) moves by (0, 1, 0)."""
    bind = np.stack([np.eye(4), np.eye(4)])
    posed = bind.copy()
    posed[1, 3, :3] = [0, 2, 0]
    pts = np.array([[1.0, 0, 0], [0, 0, 1]])
    ind = np.array([[0, 1], [1, 0]])
    w = np.array([[0.5, 0.5], [1.0, 0.0]])
    mats = np.linalg.inv(bind) @ posed
    out = skin_points(pts, ind, w, mats)
    np.testing.assert_allclose(out, [[1, 1, 0], [0, 2, 1]])
