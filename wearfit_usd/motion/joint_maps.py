"""Automatic joint-name mapping between skeleton conventions (BVH or USD).

Every known convention is a table from canonical *roles* (``hips``,
``spine_lower``, ``spine_mid``, ``chest``, ``neck``, ``neck_upper``,
``head``, and per side ``thigh_l``, ``shin_l``, ``foot_l``, ``toe_l``,
``clavicle_l``, ``upper_arm_l``, ``forearm_l``, ``hand_l``, fingers...) to
joint names. :func:`map_joints` detects the convention of each name list
(the table that recognises most names), pairs joints that play the same
role, then pairs remaining joints whose normalised names are equal.

Names are compared after normalisation: namespaces/prefixes dropped
(``mixamorig:``, ``DEF-``, ``ORG-``, ``Armature|``), case folded, separators
removed, and the side marker (``Left``/``Right``, ``L``/``R`` or ``l``/``r``
before a capital, ``l_``/``left_``, ``_l``/``.L``/``-left``...) turned into a
side tag, so ``thigh.L``, ``thigh_l``, ``l_thigh`` and ``LeftThigh`` are the
same key.
"""
from __future__ import annotations

import functools
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError

# --------------------------------------------------------------------------
# name normalisation

_PREFIX = re.compile(r"^(?:.*[:|])?(?:(?:def|org|mch|drv)[-_.]|mixamorig\d*[_:]?|bip0?1[ _]?|"
                     r"cc_base_|b_)?", re.IGNORECASE)


@functools.lru_cache(maxsize=8192)  # pure; retargeting asks for the same names many times
def normalize(name: str) -> tuple[str, str]:
    """Joint name -> (side, base): side "l", "r" or "", base lower-case
    alphanumerics. ``"mixamorig:LeftUpLeg"`` -> ("l", "upleg"),
    ``"thigh.L"`` / ``"thigh_l"`` / ``"lThigh"`` -> ("l", "thigh")."""
    n = str(name).strip()
    n = _PREFIX.sub("", n, count=1) or n
    side = ""
    m = re.match(r"^(Left|Right)(?=[A-Z0-9_.\- ])(.*)$", n) or re.match(r"^(Left|Right)(.+)$", n)
    if m:
        side, n = m.group(1)[0].lower(), m.group(2)
    else:
        m = (re.match(r"^(L|R|l|r)(?=[A-Z])(.+)$", n)
             or re.match(r"^(left|right|l|r)[_.\- ](.+)$", n, re.IGNORECASE))
        if m:
            side, n = m.group(1)[0].lower(), m.group(2)
        else:
            m = re.match(r"^(.+?)[_.\- ](left|right|l|r)(?:[_.\-](\d+))?$", n, re.IGNORECASE)
            if m:
                side, n = m.group(2)[0].lower(), m.group(1) + (m.group(3) or "")
            else:
                m = re.match(r"^(.+?)(Left|Right)$", n)
                if m:
                    side, n = m.group(2)[0].lower(), m.group(1)
    base = re.sub(r"[^a-z0-9]", "", n.lower())
    return side, base


def _key(name: str) -> str:
    side, base = normalize(name)
    return f"{side}:{base}"


# --------------------------------------------------------------------------
# convention tables: role -> name templates. "{Side}" -> Left/Right,
# "{S}" -> L/R, "{s}" -> l/r, "{side}" -> left/right. A role may list
# alternatives separated by "|".

_FINGERS = ("thumb", "index", "middle", "ring", "pinky")

_CONVENTIONS: dict[str, dict[str, str]] = {
    "cmu_motionbuilder": {
        "hips": "Hips", "spine_lower": "LowerBack", "spine_mid": "Spine", "chest": "Spine1",
        "neck": "Neck", "neck_upper": "Neck1", "head": "Head",
        "hip_joint": "{S}HipJoint", "thigh": "{Side}UpLeg", "shin": "{Side}Leg",
        "foot": "{Side}Foot", "toe": "{Side}ToeBase", "clavicle": "{Side}Shoulder",
        "upper_arm": "{Side}Arm", "forearm": "{Side}ForeArm", "hand": "{Side}Hand",
        "finger_base": "{Side}FingerBase", "index1": "{Side}HandIndex1|{Side}HandFinger1",
        "thumb1": "{S}Thumb",
    },
    "cmu_3dsmax": {
        "hips": "Hips", "spine_lower": "lowerback", "spine_mid": "Chest", "chest": "Chest2",
        "neck": "lowerneck", "neck_upper": "Neck", "head": "Head",
        "hip_joint": "{S}HipJoint", "thigh": "{Side}Hip", "shin": "{Side}Knee",
        "foot": "{Side}Ankle", "toe": "{Side}Toe", "clavicle": "{Side}Collar",
        "upper_arm": "{Side}Shoulder", "forearm": "{Side}Elbow", "hand": "{Side}Wrist",
        "finger_base": "{s}hand", "index1": "{S}Fingers", "thumb1": "{S}Thumb",
    },
    "daz": {
        "hips": "hip", "spine_lower": "abdomen", "chest": "chest", "neck": "neck", "head": "head",
        "eye": "{side}Eye", "hip_joint": "{s}Buttock", "thigh": "{s}Thigh", "shin": "{s}Shin",
        "foot": "{s}Foot", "clavicle": "{s}Collar", "upper_arm": "{s}Shldr",
        "forearm": "{s}ForeArm", "hand": "{s}Hand",
        **{f"{f}{k}": f"{{s}}{d}{k}" for f, d in zip(_FINGERS, ("Thumb", "Index", "Mid", "Ring", "Pinky"))
           for k in (1, 2, 3)},
    },
    "mixamo": {
        "hips": "Hips", "spine_lower": "Spine", "spine_mid": "Spine1", "chest": "Spine2",
        "neck": "Neck", "head": "Head", "thigh": "{Side}UpLeg", "shin": "{Side}Leg",
        "foot": "{Side}Foot", "toe": "{Side}ToeBase", "clavicle": "{Side}Shoulder",
        "upper_arm": "{Side}Arm", "forearm": "{Side}ForeArm", "hand": "{Side}Hand",
        **{f"{f}{k}": f"{{Side}}Hand{f.capitalize()}{k}" for f in _FINGERS for k in (1, 2, 3)},
    },
    # MPFB/MakeHuman "game_engine" rig = Unreal mannequin naming
    "game_engine": {
        "root": "Root", "hips": "pelvis", "spine_lower": "spine_01", "spine_mid": "spine_02",
        "chest": "spine_03", "neck": "neck_01", "head": "head",
        "thigh": "thigh_{s}", "shin": "calf_{s}", "foot": "foot_{s}", "toe": "ball_{s}",
        "clavicle": "clavicle_{s}", "upper_arm": "upperarm_{s}", "forearm": "lowerarm_{s}",
        "hand": "hand_{s}",
        **{f"{f}{k}": f"{f}_0{k}_{{s}}" for f in _FINGERS for k in (1, 2, 3)},
    },
    "makehuman_default": {
        "hips": "root", "spine_lower": "spine05", "spine_lower2": "spine04", "spine_mid": "spine03",
        "spine_mid2": "spine02", "chest": "spine01", "neck": "neck01", "neck_mid": "neck02",
        "neck_upper": "neck03", "head": "head", "jaw": "jaw", "eye": "eye.{S}",
        "hip_joint": "pelvis.{S}", "thigh": "upperleg01.{S}", "thigh_twist": "upperleg02.{S}",
        "shin": "lowerleg01.{S}", "shin_twist": "lowerleg02.{S}", "foot": "foot.{S}",
        "toe": "toe3-1.{S}", "clavicle": "clavicle.{S}", "shoulder": "shoulder01.{S}",
        "upper_arm": "upperarm01.{S}", "upper_arm_twist": "upperarm02.{S}",
        "forearm": "lowerarm01.{S}", "forearm_twist": "lowerarm02.{S}", "hand": "wrist.{S}",
        **{f"{f}{k}": f"finger{i}-{k}.{{S}}" for i, f in enumerate(_FINGERS, 1) for k in (1, 2, 3)},
    },
    "smpl": {
        "hips": "pelvis", "spine_lower": "spine1", "spine_mid": "spine2", "chest": "spine3",
        "neck": "neck", "head": "head", "jaw": "jaw", "thigh": "{side}_hip",
        "shin": "{side}_knee", "foot": "{side}_ankle", "toe": "{side}_foot",
        "clavicle": "{side}_collar", "upper_arm": "{side}_shoulder", "forearm": "{side}_elbow",
        "hand": "{side}_wrist", "finger_base": "{side}_hand",
        **{f"{f}{k}": f"{{side}}_{f}{k}" for f in _FINGERS for k in (1, 2, 3)},
    },
    "rigify": {
        "hips": "spine", "spine_lower": "spine.001", "spine_mid": "spine.002", "chest": "spine.003",
        "neck": "spine.004", "neck_upper": "spine.005", "head": "spine.006",
        "hip_joint": "pelvis.{S}", "thigh": "thigh.{S}", "shin": "shin.{S}", "foot": "foot.{S}",
        "toe": "toe.{S}", "clavicle": "shoulder.{S}", "upper_arm": "upper_arm.{S}",
        "forearm": "forearm.{S}", "hand": "hand.{S}",
        **{f"{f}{k}": (f"thumb.0{k}.{{S}}" if f == "thumb" else f"f_{f}.0{k}.{{S}}")
           for f in _FINGERS for k in (1, 2, 3)},
    },
    # VRM humanoid bone names and Godot's SkeletonProfileHumanoid (LeftUpperLeg...)
    "vrm_godot": {
        "hips": "Hips|hips", "spine_lower": "Spine|spine", "chest": "Chest|chest",
        "spine_mid": "UpperChest|upperChest", "neck": "Neck|neck", "head": "Head|head",
        "thigh": "{Side}UpperLeg|{side}UpperLeg", "shin": "{Side}LowerLeg|{side}LowerLeg",
        "foot": "{Side}Foot|{side}Foot", "toe": "{Side}Toes|{side}Toes",
        "clavicle": "{Side}Shoulder|{side}Shoulder", "upper_arm": "{Side}UpperArm|{side}UpperArm",
        "forearm": "{Side}LowerArm|{side}LowerArm", "hand": "{Side}Hand|{side}Hand",
    },
    # VRoid exports (J_Bip_C_Hips, J_Bip_L_UpperLeg...)
    "vroid": {
        "hips": "J_Bip_C_Hips", "spine_lower": "J_Bip_C_Spine", "chest": "J_Bip_C_Chest",
        "spine_mid": "J_Bip_C_UpperChest", "neck": "J_Bip_C_Neck", "head": "J_Bip_C_Head",
        "thigh": "J_Bip_{S}_UpperLeg", "shin": "J_Bip_{S}_LowerLeg", "foot": "J_Bip_{S}_Foot",
        "toe": "J_Bip_{S}_ToeBase", "clavicle": "J_Bip_{S}_Shoulder", "upper_arm": "J_Bip_{S}_UpperArm",
        "forearm": "J_Bip_{S}_LowerArm", "hand": "J_Bip_{S}_Hand",
    },
    # Bandai-Namco motion dataset style (joint_Root above Hips; Shoulder_L...)
    "bandai": {
        "root": "joint_Root", "hips": "Hips", "spine_lower": "Spine", "chest": "Chest",
        "neck": "Neck", "head": "Head", "thigh": "UpperLeg_{S}", "shin": "LowerLeg_{S}",
        "foot": "Foot_{S}", "toe": "Toes_{S}", "clavicle": "Shoulder_{S}", "upper_arm": "UpperArm_{S}",
        "forearm": "LowerArm_{S}", "hand": "Hand_{S}",
    },
    # Khronos glTF sample figures (RiggedFigure, CesiumMan: torso_joint_1, leg_joint_L_1...)
    "gltf_sample": {
        "hips": "torso_joint_1", "spine_lower": "torso_joint_2", "chest": "torso_joint_3",
        "neck": "neck_joint_1", "head": "neck_joint_2", "thigh": "leg_joint_{S}_1",
        "shin": "leg_joint_{S}_2", "foot": "leg_joint_{S}_3", "toe": "leg_joint_{S}_5",
        "upper_arm": "arm_joint_{S}_1", "forearm": "arm_joint_{S}_2", "hand": "arm_joint_{S}_3",
    },
}
_CONVENTIONS["unreal"] = _CONVENTIONS["game_engine"]

_SIDE_FORMS = {"l": {"Side": "Left", "S": "L", "s": "l", "side": "left"},
               "r": {"Side": "Right", "S": "R", "s": "r", "side": "right"}}


def _expand(table: dict[str, str]) -> dict[str, str]:
    """role table -> {normalised key: role} (sided roles get _l/_r)."""
    out: dict[str, str] = {}
    for role, templates in table.items():
        for tmpl in templates.split("|"):
            if "{" in tmpl:
                for side, forms in _SIDE_FORMS.items():
                    out.setdefault(_key(tmpl.format(**forms)), f"{role}_{side}")
            else:
                out.setdefault(_key(tmpl), role)
    return out


_KEYS = {name: _expand(t) for name, t in _CONVENTIONS.items()}


def conventions() -> list[str]:
    """Names of the built-in conventions."""
    return list(_CONVENTIONS)


def detect_convention(names) -> tuple[str | None, int]:
    """(best convention, number of names it recognises) for a joint list."""
    keys = [_key(n) for n in names]
    raw = " ".join(names).lower()
    best, score = None, 0
    for conv, table in _KEYS.items():
        s = sum(k in table for k in keys)
        if conv == "mixamo" and "mixamorig" in raw:
            s += len(keys)
        if conv == "rigify" and ("def-" in raw or "org-" in raw):
            s += 3
        if s > score:
            best, score = conv, s
    return (best, score) if score >= 3 else (None, score)


def roles(names) -> dict[str, str]:
    """{role: joint name} for a joint list, with its detected convention."""
    conv, _ = detect_convention(names)
    out: dict[str, str] = {}
    if conv is None:
        return out
    table = _KEYS[conv]
    for n in names:
        r = table.get(_key(n))
        if r is not None and r not in out:
            out[r] = n
    return out


# --------------------------------------------------------------------------

@dataclass
class JointMapping:
    """target joint name -> source joint name.

    how: target joint -> "role:<role>", "name" (equal normalised names) or
    "user" (from a JSON map).
    """
    pairs: dict[str, str]
    unmapped_source: list[str]
    unmapped_target: list[str]
    source_convention: str | None = None
    target_convention: str | None = None
    how: dict[str, str] = field(default_factory=dict)

    def __len__(self):
        return len(self.pairs)

    def get(self, target: str, default=None):
        return self.pairs.get(target, default)

    def report(self) -> dict:
        return {"source_convention": self.source_convention,
                "target_convention": self.target_convention,
                "mapped": len(self.pairs), "pairs": dict(self.pairs),
                "unmapped_source": list(self.unmapped_source),
                "unmapped_target": list(self.unmapped_target)}


def map_joints(source_names, target_names, user_map: dict | None = None) -> JointMapping:
    """Pair target joints with source joints by name.

    source_names: joints of the motion (BVH) or of a skeleton; target_names:
    joints of the skeleton to drive. user_map: {target: source} entries that
    override the automatic ones (``None`` as a value unmaps a target joint);
    names must exist (raises ``KeyError`` with the bad names otherwise).
    Each source joint is used at most once, except through ``user_map``.
    """
    src = [str(n) for n in source_names]
    tgt = [str(n) for n in target_names]
    sconv, _ = detect_convention(src)
    tconv, _ = detect_convention(tgt)
    srole = roles(src)
    trole = roles(tgt)
    pairs: dict[str, str] = {}
    how: dict[str, str] = {}
    used: set[str] = set()
    for role, t in trole.items():
        s = srole.get(role)
        if s is not None and s not in used:
            pairs[t] = s
            how[t] = f"role:{role}"
            used.add(s)
    # equal normalised names (same convention, or fingers etc. not in tables)
    skey: dict[str, str] = {}
    for n in src:
        skey.setdefault(_key(n), n)
    for t in tgt:
        if t in pairs:
            continue
        s = skey.get(_key(t))
        if s is not None and s not in used:
            pairs[t] = s
            how[t] = "name"
            used.add(s)
    if user_map:
        bad_t = [t for t in user_map if t not in tgt]
        bad_s = [s for s in user_map.values() if s is not None and s not in src]
        if bad_t or bad_s:
            msg = []
            if bad_t:
                msg.append(f"target joints not in the skeleton: {bad_t}")
            if bad_s:
                msg.append(f"source joints not in the motion: {bad_s}")
            raise KeyError("; ".join(msg))
        for t, s in user_map.items():
            if s is None:
                pairs.pop(t, None)
                how.pop(t, None)
                continue
            # a source joint given explicitly replaces its automatic use
            for other, so in list(pairs.items()):
                if so == s and other != t and how.get(other) != "user":
                    del pairs[other]
                    how.pop(other, None)
            pairs[t] = s
            how[t] = "user"
    pairs = {t: pairs[t] for t in tgt if t in pairs}  # target order
    used = set(pairs.values())
    return JointMapping(pairs=pairs,
                        unmapped_source=[s for s in src if s not in used],
                        unmapped_target=[t for t in tgt if t not in pairs],
                        source_convention=sconv, target_convention=tconv,
                        how={t: how[t] for t in pairs})


def load_user_map(path, source_names=None, target_names=None) -> dict[str, str | None]:
    """Read a JSON mapping file ``{"target_joint": "source_joint", ...}``
    (``null`` unmaps a target joint). With ``source_names``/``target_names``
    the names are checked. Raises :class:`InputError` for a bad file."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(p, "joint map file not found") from None
    except json.JSONDecodeError as exc:
        raise InputError(p, f"not valid JSON: {exc.msg}", line=exc.lineno) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(p, f"cannot read joint map: {exc}") from None
    if not isinstance(data, dict):
        raise InputError(p, 'joint map must be a JSON object {"target_joint": "source_joint"}')
    for k, v in data.items():
        if not (v is None or isinstance(v, str)):
            raise InputError(p, f"joint map entry {k!r}: value must be a joint name string or null, "
                                f"got {v!r}")
    if target_names is not None:
        bad = [k for k in data if k not in set(target_names)]
        if bad:
            raise InputError(p, f"target joints not in the skeleton: {bad}")
    if source_names is not None:
        bad = [v for v in data.values() if v is not None and v not in set(source_names)]
        if bad:
            raise InputError(p, f"source joints not in the motion: {bad}")
    return data
