"""The skinned copies' rest points fitted to example poses (animate.skin_fit)."""
import numpy as np
import pytest

from wearfit_usd.animate.skin_fit import (
    TRAINING_CLIPS,
    FrameRecorder,
    fit_rest_points,
    fit_skinned_items,
    training_motion,
)
from wearfit_usd.model import Mesh
from wearfit_usd.motion.skinning import Skinner
from wearfit_usd.transforms import axis_rotation


def _mats(rot_deg: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """(F, 2, 4, 4) row-vector skinning matrices: joint 0 fixed, joint 1
    turned about Z by ``rot_deg`` (F,) and shifted by ``shift`` (F, 3)."""
    f = len(rot_deg)
    m = np.tile(np.eye(4), (f, 2, 1, 1))
    m[:, 1, :3, :3] = axis_rotation(2, np.radians(rot_deg))
    m[:, 1, 3, :3] = shift
    return m


def _plane(z: float = 0.0, half: float = 1.0):
    """A square of two triangles at height ``z`` facing +Z (its outside)."""
    pts = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], dtype=np.float64)
    return pts, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


def test_the_rest_points_that_skinning_carries_onto_the_targets_are_recovered():
    """Targets made by skinning known rest points: with a negligible rest
    weight the least squares returns those points (any weights, any poses)."""
    rng = np.random.default_rng(3)
    m, f = 50, 12
    truth = rng.normal(size=(m, 3)) * 0.3
    ji = np.tile([0, 1], (m, 1))
    w1 = rng.uniform(0.1, 0.9, m)
    jw = np.stack([1 - w1, w1], axis=1)
    mats = _mats(rng.uniform(-60, 60, f), rng.normal(size=(f, 3)) * 0.1)
    targets = Skinner(truth, ji, jw, 2)(mats)
    start = truth + rng.normal(size=(m, 3)) * 0.02  # the static dress, 2 cm off
    got = fit_rest_points(start, ji, jw, mats, targets, rest_weight=1e-9, max_move=None)
    np.testing.assert_allclose(got, truth, atol=1e-6)
    # the move limit shortens each move to it, along the same direction
    capped = fit_rest_points(start, ji, jw, mats, targets, rest_weight=1e-9, max_move=0.01)
    step = np.linalg.norm(truth - start, axis=1)
    assert (step > 0.01).sum() > 10
    np.testing.assert_allclose(np.linalg.norm(capped - start, axis=1), np.minimum(step, 0.01), atol=1e-6)
    np.testing.assert_allclose(capped - start, (truth - start) * np.minimum(1, 0.01 / step)[:, None], atol=1e-6)
    # and a heavy rest weight keeps the static dress
    kept = fit_rest_points(start, ji, jw, mats, targets, rest_weight=1e6)
    np.testing.assert_allclose(kept, start, atol=1e-5)
    # in between: the closed form of one vertex on one joint (R = I, t = shift):
    # F (p - p0) + mu F (p - p0) ... p = (sum (y - t) + mu F p0) / (F + mu F)
    one = fit_rest_points(start, np.zeros((m, 2), dtype=np.int64), np.tile([1.0, 0.0], (m, 1)), mats,
                          targets, rest_weight=0.5, max_move=None)
    want = (targets.sum(axis=0) + 0.5 * f * start) / (f + 0.5 * f)  # joint 0 is the identity
    np.testing.assert_allclose(one, want, atol=1e-9)


def test_the_clearance_term_lifts_a_point_that_skinning_sinks_into_the_body():
    """A vertex 1 mm over a plane, its joint lowered 4 mm in some frames
    while the redress stays over the plane: the least squares alone leaves it
    under the plane in those frames; the clearance term lifts its rest point
    until the lowest frame is within a fraction of a millimetre of the
    clearance asked (min(static 1 mm, margin 2 mm) = 1 mm), and a vertex
    that never comes near the plane is not moved by it."""
    plane, faces = _plane(0.0)
    f = 8
    drop = np.zeros((f, 3))
    drop[:4, 2] = -0.004
    mats = _mats(np.zeros(f), drop)
    rest = np.array([[0.1, 0.0, 0.001], [0.2, 0.1, 0.05]])
    ji = np.array([[1, 0], [1, 0]])
    jw = np.array([[1.0, 0.0], [1.0, 0.0]])
    # the redress: over the plane by its clearance in every frame
    targets = np.repeat(rest[None], f, axis=0)
    bodies = np.repeat(plane[None], f, axis=0)
    clear0 = rest[:, 2].copy()
    plain = fit_rest_points(rest, ji, jw, mats, targets)
    lifted = fit_rest_points(rest, ji, jw, mats, targets, faces, bodies, clear0)
    lowest = lambda p: (p[:, None, 2] + drop[None, :, 2]).min(axis=1)  # noqa: E731
    assert lowest(plain)[0] < -0.0015             # the least squares: half way, still under the plane
    assert lowest(lifted)[0] > 0.0006             # lifted to nearly its 1 mm
    assert lowest(lifted)[0] < 0.0011
    np.testing.assert_allclose(lifted[1], plain[1], atol=1e-12)  # never near: untouched
    np.testing.assert_allclose(lifted[:, :2], rest[:, :2], atol=1e-9)  # only along the normal


def test_fit_rest_points_refuses_mismatched_inputs():
    mats = _mats(np.zeros(3), np.zeros((3, 3)))
    rest = np.zeros((4, 3))
    ji, jw = np.zeros((4, 1), dtype=np.int64), np.ones((4, 1))
    with pytest.raises(ValueError, match="do not match"):
        fit_rest_points(rest, ji, jw, mats, np.zeros((2, 4, 3)))
    with pytest.raises(ValueError, match="clearance term"):
        fit_rest_points(rest, ji, jw, mats, np.zeros((3, 4, 3)), bodies=np.zeros((3, 4, 3)))


def test_the_frame_recorder_keeps_every_nth_frame_and_the_free_mask():
    rec = FrameRecorder(every=3)
    with pytest.raises(ValueError, match="no frames"):
        rec.arrays()
    rec.start(np.array([True, False]))
    for f in range(7):
        rec.add(f, np.full((2, 4, 4), f), np.full((5, 3), f), np.full((2, 3), f))
    mats, bodies, items = rec.arrays()
    assert mats.shape == (3, 2, 4, 4) and bodies.shape == (3, 5, 3) and items.shape == (3, 2, 3)
    assert list(items[:, 0, 0]) == [0, 3, 6]
    assert list(rec.free) == [True, False]
    with pytest.raises(ValueError):
        FrameRecorder(every=0)


def test_the_training_motion_is_the_package_clips_one_after_the_other():
    from wearfit_usd.demo.samples import motion_path
    from wearfit_usd.io.bvh import read_bvh
    clips = [read_bvh(motion_path(c)) for c in TRAINING_CLIPS]
    m = training_motion()
    assert m.n_frames == sum(c.n_frames for c in clips) == len(m.values)
    np.testing.assert_array_equal(m.values[:clips[0].n_frames], clips[0].values)
    np.testing.assert_array_equal(m.values[-clips[-1].n_frames:], clips[-1].values)
    # the arm raise and the squat end standing as the next clip starts (no jump of the root)
    ends = np.cumsum([c.n_frames for c in clips])[:-1]
    assert np.abs(m.values[ends] - m.values[ends - 1])[:, :3].max() < 5.0  # centimetres


def test_fit_skinned_items_keeps_free_and_kept_vertices_and_names():
    """Vertices marked free by the frames (cloth, items skinned whole) and
    those in ``keep`` keep their points; the others move; names, faces and
    influences are the copies' own."""
    plane, faces = _plane(0.0)
    f = 6
    drop = np.zeros((f, 3))
    drop[:3, 2] = -0.004
    mats = _mats(np.zeros(f), drop)
    pts = np.array([[0.1, 0.0, 0.001], [0.2, 0.0, 0.001], [0.3, 0.0, 0.001], [0.4, 0.0, 0.001]])
    ji = np.tile([1, 0], (4, 1))
    jw = np.tile([1.0, 0.0], (4, 1))
    none = np.zeros(0, dtype=np.int64)
    a = Mesh("suit_skinned", pts[:2].copy(), np.zeros((0, 3), dtype=np.int64), none, none, none,
             joint_indices=ji[:2], joint_weights=jw[:2])
    b = Mesh("hat_skinned", pts[2:].copy(), np.zeros((0, 3), dtype=np.int64), none, none, none,
             joint_indices=ji[2:], joint_weights=jw[2:])
    frames = (mats, np.repeat(plane[None], f, axis=0), np.repeat(pts[None], f, axis=0),
              np.array([False, True, False, False]))
    out, moved = fit_skinned_items([a, b], faces, plane, frames, keep=np.array([False, False, True, False]))
    assert [m.name for m in out] == ["suit_skinned", "hat_skinned"]
    assert moved[0] > 0.001 and moved[3] > 0.001
    assert moved[1] == 0.0 and moved[2] == 0.0
    np.testing.assert_array_equal(out[0].joint_indices, ji[:2])
    np.testing.assert_array_equal(a.points, pts[:2])  # the inputs are left alone
    with pytest.raises(ValueError, match="example points"):
        fit_skinned_items([a], faces, plane, frames)


def test_example_frames_that_cannot_be_made_leave_the_items_as_dressed(monkeypatch):
    """When the example clips cannot be put on the target (here: the
    retargeting refuses), the fit is skipped with a warning naming the
    target and the reason, instead of failing the dressing."""
    import wearfit_usd.animate.skin_fit as sf
    from wearfit_usd.errors import InputError

    def refuse(*args, **kwargs):
        raise InputError("clip.bvh", "key joints not paired: LeftUpLeg")

    monkeypatch.setattr(sf, "training_frames", refuse)

    class Target:
        source = "odd_rig.usdc"

    with pytest.warns(UserWarning, match=r"odd_rig\.usdc.*not fitted to example poses.*LeftUpLeg"):
        assert sf.example_frames(None, Target(), None, None) is None


def test_an_inner_layer_does_not_move_out_through_the_layer_over_it():
    """Two layers 4 mm apart over a plane (normal +Z): the inner vertex
    fitted 6 mm out while the outer one stayed is brought back to half the
    gap (2 mm); one fitted 1 mm out is left; sideways moves are kept; a
    vertex under nothing keeps any move."""
    from wearfit_usd.animate.skin_fit import keep_layer_order
    rest = np.array([[0.0, 0.0, 0.002], [0.1, 0.0, 0.002], [0.0, 0.0, 0.006], [0.1, 0.0, 0.006],
                     [0.5, 0.0, 0.002]])
    fitted = rest.copy()
    fitted[0] += [0.001, 0.0, 0.006]   # out through the outer layer, and 1 mm sideways
    fitted[1, 2] += 0.001              # out, under the outer layer still
    fitted[4, 2] += 0.006              # under nothing
    normal = np.tile([0.0, 0.0, 1.0], (5, 1))
    got = keep_layer_order(rest, fitted, normal, rest[:, 2], np.array([0, 1]), np.array([2, 3]))
    np.testing.assert_allclose(got[0], [0.001, 0.0, 0.004], atol=1e-12)
    np.testing.assert_allclose(got[1:], fitted[1:], atol=1e-12)
    # the outer vertex moved out 3 mm: the inner one may follow to 3 + 2 mm
    fitted[2, 2] += 0.003
    got = keep_layer_order(rest, fitted, normal, rest[:, 2], np.array([0, 1]), np.array([2, 3]))
    np.testing.assert_allclose(got[0, 2], 0.002 + 0.005, atol=1e-12)


@pytest.mark.slow
def test_example_frames_made_once_serve_several_shots(tmp_path, monkeypatch):
    """The example poses depend on the reference and the target only: made
    once (``training_frames``) and passed as ``AnimateOptions.skin_examples``
    they are used as they are (none are made again) and give the shot the
    same skinned copies as a shot that makes its own."""
    import wearfit_usd.animate.try_on as try_on
    from tests.conftest import BVH_DIR, USD_DIR
    from wearfit_usd.animate.skin_fit import training_frames
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    ref, tgt = read_character(USD_DIR / "ref_female.usda"), read_character(USD_DIR / "body_female_thin.usdc")
    motion = read_bvh(BVH_DIR / "cmu_07_01_walk.bvh")
    opt = AnimateOptions(start=1, end=9, items="skinned")
    own = animate(ref, tgt, motion, tmp_path / "own.usdc", opt)
    examples = training_frames(ref, tgt, None, AnimateOptions())
    assert len(examples[0]) == own.skin_fit["frames"] == 40

    def made_again(*args, **kwargs):
        raise AssertionError("example frames made again")

    monkeypatch.setattr(try_on, "example_frames", made_again)
    from dataclasses import replace
    shared = animate(ref, tgt, motion, tmp_path / "shared.usdc", replace(opt, skin_examples=examples))
    assert shared.skin_fit == own.skin_fit
    from pxr import Usd, UsdGeom
    a, b = Usd.Stage.Open(str(tmp_path / "own.usdc")), Usd.Stage.Open(str(tmp_path / "shared.usdc"))
    meshes = [p for p in a.Traverse() if p.IsA(UsdGeom.Mesh) and "casualsuit" in p.GetName()]
    assert meshes
    for p in meshes:
        np.testing.assert_array_equal(np.array(UsdGeom.Mesh(p).GetPointsAttr().Get()),
                                      np.array(UsdGeom.Mesh(b.GetPrimAtPath(p.GetPath())).GetPointsAttr().Get()))
