"""BVH units, position channels, a root above the hips, and feet on the floor:
every clip (CMU and third-party) on ref_male's, ref_female's and the
mannequin's bodies."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import DATA  # the data card's folder beside the checkout
from wearfit_usd.errors import InputError
from wearfit_usd.io.bvh import read_bvh
from wearfit_usd.io.bvh_units import choose_unit, position_mode, standing_height
from wearfit_usd.motion.clip_check import LIMITS, clip_on_body, within_limits
from wearfit_usd.motion.floor import place_on_floor
from wearfit_usd.motion.retarget import retarget
from wearfit_usd.motion.rig_match import KEY_ROLES

THIRD = DATA / "thirdparty"
CLIPS = sorted((DATA / "bvh").glob("*.bvh")) + sorted((THIRD / "bvh").glob("*.bvh"))
BODIES = {"ref_male": DATA / "usd" / "ref_male.usda", "ref_female": DATA / "usd" / "ref_female.usda",
          "mannequin": THIRD / "bodies" / "mannequiny_idle_blender.usdc"}


@pytest.fixture(scope="module")
def bodies():
    from wearfit_usd.io.usd import read_character
    return {k: read_character(v) for k, v in BODIES.items()}


@pytest.mark.slow
@pytest.mark.parametrize("clip", CLIPS, ids=[c.stem for c in CLIPS])
def test_clips_on_bodies_floor_and_travel(clip, bodies):
    for name, char in bodies.items():
        r = clip_on_body(clip, char)
        msg = f"{clip.name} on {name}: {r}"
        assert r["mapped"], msg
        assert abs(r["frame0_cm"]) <= LIMITS["frame0_cm"], msg  # FRAME0_SLACK_M = 2.5 cm at most
        assert abs(r["median_cm"]) <= LIMITS["median_cm"], msg
        assert r["travel_err"] <= LIMITS["travel_err"], msg
        assert within_limits(r), msg


# ----------------------------------------------------------------- units

def test_units_from_standing_height():
    assert choose_unit(170.0) == (0.01, "cm")
    assert choose_unit(67.0) == (0.0254, "inch")
    assert choose_unit(1.75) == (1.0, "m")
    assert choose_unit(17.5) == (0.1, "dm")
    assert choose_unit(1750.0) == (0.001, "mm")
    assert choose_unit(31.0)[1].startswith("cmu")  # 1.75 m in CMU units
    # splayed legs lower the vertical extent; the bone path does not
    parents = np.array([-1, 0, 1, 0, 3])
    pos = np.array([[0, 0, 0], [0, 60, 0], [0, 80, 0], [45, -45, 0], [90, -90, 0]], float)
    assert standing_height(parents, pos) > np.ptp(pos[:, 1])


def _write_game_bvh(path: Path, motion, root_name="joint_Root"):
    """``motion`` rewritten as a game-studio dialect: a floor-level root joint
    above the hips, 6 channels on every joint, position channels repeating the
    OFFSETs, centimetres, Y up."""
    cm = 100.0
    names, parents = motion.joint_names, motion.parents
    children = [[] for _ in names]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    rot = motion.local_rotations()  # (F, J, 3, 3) row-vector, internal axes (= file axes: Y up)
    from wearfit_usd.transforms import matrix_to_euler
    eul = matrix_to_euler(rot, "ZXY")
    trans = motion.local_translations() * cm
    hips_h = float(-motion.rest_global_transforms()[:, 3, 1].min()) * cm
    lines = ["HIERARCHY", f"ROOT {root_name}", "{", "  OFFSET 0 0 0",
             "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
    order = []

    def emit(j, depth):
        ind = "  " * depth
        off = motion.offsets[j] * cm + (np.array([0, hips_h, 0]) if parents[j] < 0 else 0)
        lines.extend([f"{ind}JOINT {names[j]}", f"{ind}{{", f"{ind}  OFFSET {off[0]:.5f} {off[1]:.5f} {off[2]:.5f}",
                      f"{ind}  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"])
        order.append(j)
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:
            lines.extend([f"{ind}  End Site", f"{ind}  {{", f"{ind}    OFFSET 0 3 0", f"{ind}  }}"])
        lines.append(f"{ind}}}")

    emit(0, 1)
    lines.append("}")
    F = rot.shape[0]
    lines += ["MOTION", f"Frames: {F}", f"Frame Time: {motion.frame_time:.7f}"]
    for f in range(F):
        row = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]  # joint_Root stays at the origin
        for j in order:
            t = trans[f, j] + (np.array([0, hips_h, 0]) if parents[j] < 0 else 0)
            row += list(t) + list(eul[f, j])
        lines.append(" ".join(f"{v:.5f}" for v in row))
    path.write_text("\n".join(lines) + "\n")


def test_game_dialect_root_above_hips_positions_on_every_joint(tmp_path, bodies):
    src = read_bvh(THIRD / "bvh" / "mixamo_names_walk_turn.bvh")
    p = tmp_path / "game.bvh"
    _write_game_bvh(p, src)
    game = read_bvh(p)
    assert game.position_mode == "absolute" and game.units == "cm"
    assert game.height_m() == pytest.approx(src.height_m(), abs=0.05)
    # the same world motion as the source clip (the channels are not added twice)
    a = src.global_positions([0, 30, 60])
    b = game.global_positions([0, 30, 60])[:, 1:]
    np.testing.assert_allclose(b - b[:, :1], a - a[:, :1], atol=1e-3)
    char = bodies["ref_male"]
    r1, r2 = clip_on_body(THIRD / "bvh" / "mixamo_names_walk_turn.bvh", char), clip_on_body(p, char)
    assert r2["mapped"] and abs(r2["frame0_cm"]) <= 3 and abs(r2["median_cm"]) <= 5
    assert r2["travel_m"] == pytest.approx(r1["travel_m"], rel=0.05, abs=0.02)


def test_position_mode_rule():
    parents = np.array([-1, 0, 1])
    offsets = np.array([[0, 0, 0], [0, 10, 0], [0, 10, 0]], float)
    ch = [["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"]] * 3
    starts = np.array([0, 6, 12])
    row = np.zeros(18)
    assert position_mode(parents, offsets, ch, row, starts) == "add"  # zeros: MakeHuman's additive
    row[7] = row[13] = 10.0
    assert position_mode(parents, offsets, ch, row, starts) == "absolute"


def test_floor_keep_and_error_for_unpairable_clip(tmp_path, bodies):
    char = bodies["ref_male"]
    m = read_bvh(DATA / "bvh" / "cmu_07_01_walk.bvh")
    rt = retarget(m, char.skeleton, start=1, end=40)
    same, shift = place_on_floor(rt, char.skeleton, char.body, "keep")
    assert same is rt and shift == 0.0
    moved, shift = place_on_floor(rt, char.skeleton, char.body, "auto")
    d = moved.world[:, :, 3, 1] - rt.world[:, :, 3, 1]
    # a rigid vertical translation per frame (the capture floor's tilt levelled
    # along the travel), frame 0 moved by the constant shift, nothing horizontal
    np.testing.assert_allclose(d, d[:, :1] * np.ones_like(d), atol=1e-12)
    assert d[0, 0] == pytest.approx(shift)
    assert abs(moved.report["floor_tilt_deg"]) < 3.0
    np.testing.assert_array_equal(moved.world[:, :, 3, [0, 2]], rt.world[:, :, 3, [0, 2]])
    inplace = retarget(read_bvh(DATA / "bvh" / "cmu_02_05_punch_strike.bvh"), char.skeleton, start=1, end=60)
    moved, shift = place_on_floor(inplace, char.skeleton, char.body, "auto")
    np.testing.assert_allclose(moved.world[:, :, 3, 1] - inplace.world[:, :, 3, 1], shift, atol=1e-12)
    np.testing.assert_allclose(char.skeleton.world_from_local(moved.local), moved.world, atol=1e-9)
    # a clip with no legs cannot be paired: a clear error naming the clip and roles
    bad = tmp_path / "armless.bvh"
    bad.write_text("HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition "
                   "Zrotation Xrotation Yrotation\n JOINT b\n {\n  OFFSET 0 50 0\n  CHANNELS 3 Zrotation "
                   "Xrotation Yrotation\n  End Site\n  {\n   OFFSET 0 50 0\n  }\n }\n}\nMOTION\nFrames: 2\n"
                   "Frame Time: 0.033333\n0 90 0 0 0 0 0 0 0\n0 90 0 0 0 0 0 0 0\n")
    with pytest.raises(InputError) as e:
        retarget(read_bvh(bad), char.skeleton)
    assert "armless.bvh" in str(e.value) and "thigh_l" in str(e.value)
    assert set(KEY_ROLES) >= {"thigh_l", "hand_r"}
