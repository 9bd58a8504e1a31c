"""The per-frame evaluator gives redress.apply's numbers (binding, rigid
parts, loose-part smoothing) on the real reference and on the sample body."""
from dataclasses import replace

import numpy as np

from wearfit_usd.animate.frame_eval import FrameEvaluator
from wearfit_usd.dress.apply import apply
from wearfit_usd.dress.plan import plan
from wearfit_usd.motion.skinning import skin_points, skinning_matrices


def _posed(character, seed, angle=0.35):
    """The character's body with every joint turned a little (a pose that bends
    all limbs), (N, 3)."""
    from scipy.spatial.transform import Rotation
    skel = character.skeleton
    rng = np.random.default_rng(seed)
    local = np.array(skel.rest_local, dtype=np.float64, copy=True)
    axes = rng.normal(size=(skel.n_joints, 3))
    axes *= (angle * rng.uniform(0.2, 1.0, size=skel.n_joints) / np.linalg.norm(axes, axis=1))[:, None]
    rot = Rotation.from_rotvec(axes).as_matrix()
    local[1:, :3, :3] = rot[1:] @ local[1:, :3, :3]
    world = skel.world_from_local(local)
    mats = skinning_matrices(skel.bind_world, world)
    b = character.body
    return skin_points(b.points, b.joint_indices, b.joint_weights, mats)


def _check(character, seeds=(0, 1)):
    pl = plan(character, k=5)
    ev = FrameEvaluator(pl)
    for seed in seeds:
        body = _posed(character, seed)
        ref = apply(pl, body, character.body.faces, penetration=False)[0]
        got = ev(body)
        assert got.shape == ref.shape
        np.testing.assert_allclose(got, ref, atol=1e-12, rtol=0)
        assert np.abs(got - pl.ref_points).max() > 1e-3  # the pose moved the items
    np.testing.assert_allclose(ev(character.body.points), pl.ref_points, atol=1e-9)
    return pl


def test_matches_apply_on_the_real_reference(ref_male):
    pl = _check(ref_male)
    assert pl.rigid_groups and pl.smoother is not None and len(pl.smoother.free) > 0
    assert pl.smoother.patches  # the loose parts are smoothed in the frames of the body under them


def test_matches_apply_on_the_sample_body():
    from wearfit_usd.demo.samples import make_body, make_items
    body = make_body(resolution=0.03)
    ch = replace(body, items=make_items(body))
    _check(ch, seeds=(2,))
