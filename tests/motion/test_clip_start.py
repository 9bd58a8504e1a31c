"""Where a clip's motion starts: a converter's rest frame at its head is found
from the rotations alone (known answers on synthetic steps; the data set's
CMU conversions; `wearfit animate` skips it by default)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tests.conftest import BVH_DIR, DATA, USD_DIR
from wearfit_usd.motion.clip_start import leading_rest_frames, rotation_steps
from wearfit_usd.transforms import matrix_from_quat


def _rot_x(deg):
    h = np.radians(deg) / 2
    return matrix_from_quat(np.array([np.cos(h), np.sin(h), 0.0, 0.0]))


def _motion(angles):
    """A 2-joint clip: joint 1 turns about x by ``angles`` (degrees) per frame."""
    rots = np.stack([np.stack([np.eye(3), _rot_x(a)]) for a in angles])
    return SimpleNamespace(n_frames=len(angles), local_rotations=lambda frames: rots[frames])


def test_rotation_steps_known_answers():
    steps = rotation_steps(_motion([0.0, 90.0, 95.0, 93.0]).local_rotations(np.arange(4)))
    np.testing.assert_allclose(steps, [90.0, 5.0, 2.0], atol=1e-6)
    with pytest.raises(ValueError):
        rotation_steps(np.zeros((3, 2, 3)))


def test_rest_frame_is_a_large_first_step():
    walk = 40.0 + 10.0 * np.sin(np.arange(60) / 5.0)   # steps of at most 2 degrees
    assert leading_rest_frames(_motion(np.r_[0.0, walk])) == 1          # 30 degrees and more in one frame
    assert leading_rest_frames(_motion(walk)) == 0                      # starts in motion
    assert leading_rest_frames(_motion(np.r_[30.0, walk])) == 0         # first step 10 degrees: motion
    fast = 60.0 * np.sin(np.arange(60) / 2.0)                           # steps up to ~30 degrees
    assert leading_rest_frames(_motion(np.r_[fast[0] + 45.0, fast])) == 0  # not 2x the later steps
    assert leading_rest_frames(_motion([0.0, 90.0])) == 0               # too short to tell


def test_rest_blended_into_the_motion_over_a_few_frames():
    walk = 40.0 + 10.0 * np.sin(np.arange(60) / 5.0)   # steps of at most 2 degrees
    blend = np.r_[-44.0, -20.0, 4.0, 24.0]              # 24, 24, 20 and 16 degrees to walk[0] = 40
    assert leading_rest_frames(_motion(np.r_[blend, walk])) == 4          # the motion starts at frame 4
    assert leading_rest_frames(_motion(np.r_[16.0, 28.0, walk])) == 0     # 12 + 12 degrees: too little
    ramp = np.cumsum(np.full(12, 20.0))                                   # 20 degrees a frame for 11 frames
    assert leading_rest_frames(_motion(np.r_[ramp, ramp[-1] + walk - 40.0])) == 0  # fast motion, not a rest


def test_the_data_sets_cmu_conversions_start_with_a_rest_frame():
    from wearfit_usd.io.bvh import read_bvh
    found = {p.name: leading_rest_frames(read_bvh(p)) for p in sorted(BVH_DIR.glob("*.bvh"))}
    third = {p.name: leading_rest_frames(read_bvh(p)) for p in sorted((DATA / "thirdparty" / "bvh").glob("*.bvh"))}
    for name in ("cmu_02_04_jump_balance.bvh", "cmu_02_05_punch_strike.bvh", "cmu_05_02_dance_pirouette.bvh",
                 "cmu_05_12_dance_arms_held_high.bvh", "cmu_07_01_walk.bvh", "cmu_09_11_run.bvh"):
        assert found[name] == 1, name
    # clips that start in motion, a one-frame pose
    # Daz's conversion blends its rest into the motion over four frames (24, 25, 22 and 15 degrees)
    assert found["cmudaz_02_02_walk.bvh"] == 4
    assert found["cmu3dsmax_131_01_start_walk_stop.bvh"] == 0
    assert found["mhdefault_run01_pose.bvh"] == 0
    assert third and all(v == 0 for v in third.values()), third


def test_cli_animate_skips_the_rest_frame_by_default(tmp_path, capsys):
    from pxr import Usd, UsdSkel

    from wearfit_usd.cli import main

    def first_pose(out):
        stage = Usd.Stage.Open(str(out))
        anim = UsdSkel.Animation(stage.GetPrimAtPath("/Root/Character/Animation"))
        return np.array(anim.GetRotationsAttr().Get(stage.GetStartTimeCode()))
    args = [str(USD_DIR / "ref_male.usda"), str(USD_DIR / "body_male_heavy.usdc"), str(BVH_DIR / "cmu_07_01_walk.bvh")]
    auto, zero = tmp_path / "auto.usdc", tmp_path / "zero.usdc"
    assert main(["animate", *args, "-o", str(auto), "--end", "9", "--measure-every", "0"]) == 0
    assert "converter's rest pose" in capsys.readouterr().err
    assert main(["animate", *args, "-o", str(zero), "--end", "9", "--start", "0", "-q"]) == 0
    one = tmp_path / "one.usdc"
    assert main(["animate", *args, "-o", str(one), "--end", "9", "--start", "1", "-q"]) == 0
    np.testing.assert_allclose(first_pose(auto), first_pose(one), atol=1e-6)
    assert np.abs(first_pose(auto) - first_pose(zero)).max() > 0.05
    with pytest.raises(SystemExit) as e:
        main(["animate", *args, "-o", str(tmp_path / "bad.usdc"), "--start", "soon", "-q"])
    assert e.value.code == 2
    assert not (tmp_path / "bad.usdc").exists()
