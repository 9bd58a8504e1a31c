"""Joint correspondence from structure (names scrambled) and names as hints,
on the data set's rigs, CMU clips and the third-party figures."""
from __future__ import annotations

import copy
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import DATA  # the data card's folder beside the checkout
from wearfit_usd.errors import InputError
from wearfit_usd.io.bvh import read_bvh
from wearfit_usd.motion.joint_maps import map_joints
from wearfit_usd.motion.joint_maps import roles as name_roles
from wearfit_usd.motion.rig_match import KEY_ROLES, find_roles, match_skeletons, structure_roles

THIRD = DATA / "thirdparty"
CMU = sorted((DATA / "bvh").glob("cmu*.bvh"))
CHECKED = KEY_ROLES + ("chest", "neck", "toe_l", "toe_r", "clavicle_l", "clavicle_r")


def _scramble(names, parents, pos, seed):
    """Random names, shuffled order (parents still before children)."""
    rng = np.random.default_rng(seed)
    n = len(names)
    children = [[] for _ in range(n)]
    roots = []
    for j, p in enumerate(parents):
        (children[p] if p >= 0 else roots).append(j)
    order, ready = [], list(roots)
    while ready:  # random topological order
        k = int(rng.integers(len(ready)))
        j = ready.pop(k)
        order.append(j)
        ready.extend(children[j])
    new_of = {old: new for new, old in enumerate(order)}
    new_parents = np.array([new_of[parents[o]] if parents[o] >= 0 else -1 for o in order])
    new_names = [f"j{rng.integers(1 << 30):x}_{i}" for i in range(n)]
    return new_names, new_parents, np.asarray(pos)[order], order


def _skeletons():
    from wearfit_usd.io.usd import read_character
    out = {}
    for f in ("ref_male.usda", "ref_female.usda", "body_male_cmu_rig.usdc"):
        sk = read_character(DATA / "usd" / f).skeleton
        out[f] = (sk.joint_names, sk.parents, sk.bind_positions())
    for f in CMU:
        m = read_bvh(f)
        out[f.name] = (m.joint_names, m.parents, m.rest_global_transforms()[:, 3, :3])
    return out


@pytest.fixture(scope="module")
def skeletons():
    return _skeletons()


def test_structure_finds_the_named_roles_with_scrambled_names(skeletons):
    for label, (names, parents, pos) in skeletons.items():
        truth = name_roles(names)
        for seed in (1, 2):
            sn, sp, spos, order = _scramble(names, parents, pos, seed)
            assert not name_roles(sn)  # the names give nothing away
            r = find_roles(sn, sp, spos)
            assert not r.missing(), (label, r.missing(), r.notes)
            for role in CHECKED:
                if role in truth:
                    assert names[order[r.roles[role]]] == truth[role], (label, role)
            assert min(r.confidence[k] for k in KEY_ROLES) >= 0.5


def test_scrambled_skeletons_pair_like_named_ones(skeletons):
    names, parents, pos = skeletons["ref_male.usda"]
    cn, cp, cpos = skeletons["cmu_07_01_walk.bvh"]
    named = map_joints(cn, names)
    sn, sp, spos, order = _scramble(cn, cp, cpos, 7)
    m = match_skeletons(sn, sp, spos, names, parents, pos)
    assert m.ok and not m.by_names and m.confidence > 0.5
    back = {t: cn[order[sn.index(s)]] for t, s in m.mapping.pairs.items()}
    tr = find_roles(names, parents, pos)
    for role in KEY_ROLES:
        t = names[tr.roles[role]]
        assert back[t] == named.pairs[t], role


def test_names_that_cover_the_key_roles_keep_todays_pairs(skeletons):
    names, parents, pos = skeletons["ref_male.usda"]
    for label in ("body_male_cmu_rig.usdc", "cmu_07_01_walk.bvh", "ref_female.usda"):
        sn, sp, spos = skeletons[label]
        m = match_skeletons(sn, sp, spos, names, parents, pos)
        assert m.by_names and m.ok and m.mapping.pairs == map_joints(sn, names).pairs, label


def test_third_party_figures_pair_with_the_reference(skeletons):
    from wearfit_usd.io.usd import read_character
    names, parents, pos = skeletons["ref_male.usda"]
    for f in ("RiggedFigure_blender.usdc", "RiggedFigure.usdz", "mannequiny_idle_blender.usdc"):
        sk = read_character(THIRD / "bodies" / f, require_skeleton=False).skeleton
        m = match_skeletons(sk.joint_names, sk.parents, sk.bind_positions(), names, parents, pos)
        assert m.ok, (f, m.missing)
        got = {r: m.source.joint(r) for r in KEY_ROLES}
        # names scrambled: the structure alone finds the same joints
        sn, sp, spos, order = _scramble(sk.joint_names, sk.parents, sk.bind_positions(), 5)
        ms = match_skeletons(sn, sp, spos, names, parents, pos)
        assert ms.ok and not ms.by_names and ms.confidence >= 0.5, (f, ms.missing)
        assert {r: sk.joint_names[order[ms.source.roles[r]]] for r in KEY_ROLES} == got, f
        if f.startswith("RiggedFigure"):
            assert got["thigh_l"] == "leg_joint_L_1" and got["shin_r"] == "leg_joint_R_2"
            assert got["foot_l"] == "leg_joint_L_3" and got["hand_r"] == "arm_joint_R_3"
            assert got["upper_arm_l"] == "arm_joint_L_1" and got["head"] == "neck_joint_2"
            assert got["hips"] == "torso_joint_1"
        else:
            assert got["thigh_l"] == "thigh_l" and got["hand_r"] == "hand_r" and got["head"] == "head"
    for f in ("mixamo_names_walk_turn.bvh", "inches_120fps_walk.bvh"):
        c = read_bvh(THIRD / "bvh" / f)
        m = match_skeletons(c.joint_names, c.parents, c.rest_global_transforms()[:, 3, :3], names, parents,
                            pos)
        assert m.ok and m.confidence >= 0.7, (f, m.missing)


def test_mirrored_facing_swaps_the_sides(skeletons):
    """A character facing -Z has its left at -X: sides follow the toes."""
    names, parents, pos = skeletons["cmu_07_01_walk.bvh"]
    truth = name_roles(names)
    turned = pos * np.array([-1.0, 1.0, -1.0])  # 180 degrees about Y
    sn, sp, spos, order = _scramble(names, parents, turned, 3)
    r, _, left, forward, _ = structure_roles(sn, sp, spos)
    assert forward[2] < -0.9 and left[0] < -0.9
    assert names[order[r["thigh_l"]]] == truth["thigh_l"]
    assert names[order[r["hand_r"]]] == truth["hand_r"]


def test_no_legs_is_a_clear_error(skeletons):
    from wearfit_usd.fit.body_fit import fit_body
    from wearfit_usd.io.usd import read_character
    ref = read_character(DATA / "usd" / "ref_male.usda")
    sk = ref.skeleton
    legs = {j for j, n in enumerate(sk.joint_names) if n.split("_")[0] in ("thigh", "calf", "foot", "ball")}
    keep = [j for j in range(sk.n_joints) if j not in legs]
    remap = {o: i for i, o in enumerate(keep)}
    legless = copy.copy(sk)
    legless.joint_names = [f"x{i}" for i in range(len(keep))]
    legless.parents = np.array([remap[sk.parents[o]] if sk.parents[o] >= 0 else -1 for o in keep])
    legless.bind_world = sk.bind_world[keep]
    with pytest.raises(InputError) as e:
        fit_body(ref.body.points, ref.body.faces, ref.body.points * 1.01, ref.body.faces,
                 ref_skeleton=sk, ref_joint_indices=ref.body.joint_indices,
                 ref_joint_weights=ref.body.joint_weights, target_skeleton=legless,
                 options={"target_label": "legless.usda"})
    msg = str(e.value)
    assert e.value.exit_code == 2 and "legless.usda" in msg and "thigh_l" in msg and "--no-pose" in msg
    # asked for similarity only: no error
    r = fit_body(ref.body.points, ref.body.faces, ref.body.points * 1.01, ref.body.faces,
                 ref_skeleton=sk, ref_joint_indices=ref.body.joint_indices,
                 ref_joint_weights=ref.body.joint_weights, target_skeleton=legless,
                 options={"target_label": "legless.usda", "pose_align": False})
    assert r.points.shape == ref.body.points.shape


def test_inspect_map_prints_the_pairing():
    out = subprocess.run([sys.executable, "-m", "wearfit_usd", "inspect",
                          str(THIRD / "bodies" / "RiggedFigure_blender.usdc"), "--map",
                          str(DATA / "usd" / "ref_female.usda")], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "confidence" in out.stdout and "leg_joint_L_1" in out.stdout and "thigh_l" in out.stdout
    assert "KEY ROLES NOT PAIRED" not in out.stdout


def test_name_hint_tables_for_other_conventions():
    assert name_roles(["hips", "spine", "leftUpperLeg", "rightUpperLeg", "leftLowerLeg", "leftHand"]) == {
        "hips": "hips", "spine_lower": "spine", "thigh_l": "leftUpperLeg", "thigh_r": "rightUpperLeg",
        "shin_l": "leftLowerLeg", "hand_l": "leftHand"}
    r = name_roles(["Hips", "LeftUpperLeg", "RightUpperLeg", "LeftLowerArm", "LeftToes"])
    assert r["thigh_r"] == "RightUpperLeg" and r["forearm_l"] == "LeftLowerArm" and r["toe_l"] == "LeftToes"
    r = name_roles(["J_Bip_C_Hips", "J_Bip_L_UpperLeg", "J_Bip_R_UpperLeg", "J_Bip_R_Hand"])
    assert r["thigh_l"] == "J_Bip_L_UpperLeg" and r["hand_r"] == "J_Bip_R_Hand"
    r = name_roles(["joint_Root", "Hips", "UpperLeg_L", "LowerLeg_L", "Shoulder_R", "Hand_R"])
    assert r["root"] == "joint_Root" and r["shin_l"] == "LowerLeg_L" and r["clavicle_r"] == "Shoulder_R"
