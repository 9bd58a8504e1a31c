"""Joint correspondence between two skeletons, with or without usable names.

Each skeleton gets *semantic roles* (the role names of
:mod:`wearfit_usd.motion.joint_maps`: ``hips``, ``spine_lower``,
``spine_mid``, ``chest``, ``neck``, ``head`` and per side ``thigh``,
``shin``, ``foot``, ``toe``, ``clavicle``, ``upper_arm``, ``forearm``,
``hand`` with ``_l``/``_r``) found two ways:

* **names**: the built-in convention tables (:func:`joint_maps.roles`:
  CMU, Daz, Mixamo ``mixamorig:``, Unreal/MPFB game engine, MakeHuman,
  SMPL, Rigify; Godot's ``thigh.l`` and VRM/glTF/Bandai spellings normalise
  onto them);
* **structure**: rest positions (internal space, Y up), the hierarchy,
  left/right symmetry and bone lengths. The feet are the lowest joints on
  either side of the skeleton's lateral axis (the principal horizontal axis
  of the rest pose; left = up x forward, forward = the way the toes point),
  the hips their common ancestor; the head is at the top of the chain
  above the hips, the arms the two lateral branches off that chain. Along a
  limb, (thigh, knee, ankle) and (shoulder, elbow, wrist) are the joint
  triples whose bones are straight, mostly vertical (legs), with human
  length ratios (twist joints, hip-joint and heel helpers are skipped).

Where both give a joint and agree, the role's confidence is 1; a structure
role alone gets its fit quality (0.5-0.9); where they disagree the name wins
with confidence 0.5. :func:`match_skeletons` pairs two skeletons through
their roles (and by equal names and chain position for the other joints);
a user's JSON map ``{target: source}`` overrides everything.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .joint_maps import JointMapping, map_joints
from .joint_maps import roles as name_roles

#: roles that must be paired for pose alignment and retargeting
KEY_ROLES: tuple[str, ...] = (
    "hips", "head",
    "thigh_l", "shin_l", "foot_l", "thigh_r", "shin_r", "foot_r",
    "upper_arm_l", "forearm_l", "hand_l", "upper_arm_r", "forearm_r", "hand_r",
)

_END_WORDS = ("end", "top", "nub", "tip", "site")


@dataclass
class RigRoles:
    """Semantic roles of one skeleton.

    roles: {role: joint index}; confidence: {role: 0..1}; how: {role:
    "name", "structure", "name+structure" or "user"}; left: (3,) unit
    lateral direction of the character's left; forward: (3,) unit facing
    direction; notes: what the structure search could not find.
    """
    names: list[str]
    roles: dict[str, int]
    confidence: dict[str, float]
    how: dict[str, str]
    left: np.ndarray
    forward: np.ndarray
    notes: list[str] = field(default_factory=list)

    def missing(self, wanted=KEY_ROLES) -> list[str]:
        """Key roles not found."""
        return [r for r in wanted if r not in self.roles]

    def joint(self, role: str) -> str | None:
        """Joint name playing ``role`` (None if none)."""
        j = self.roles.get(role)
        return None if j is None else self.names[j]

    def report(self) -> dict:
        return {"roles": {r: self.names[j] for r, j in self.roles.items()},
                "confidence": {r: round(c, 3) for r, c in self.confidence.items()},
                "how": dict(self.how), "missing_key_roles": self.missing(), "notes": list(self.notes)}


# --------------------------------------------------------------------------
# structure

def _children(parents) -> list[list[int]]:
    ch: list[list[int]] = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            ch[p].append(j)
    return ch


def _path_to_root(parents, j) -> list[int]:
    out = []
    while j >= 0:
        out.append(j)
        j = parents[j]
    return out


def _lca(parents, a, b) -> int:
    pa = _path_to_root(parents, a)
    sb = set(_path_to_root(parents, b))
    for j in pa:
        if j in sb:
            return j
    return -1


def _chain(parents, top, bottom) -> list[int]:
    """Joints from ``top`` (exclusive) down to ``bottom`` (inclusive)."""
    out = []
    j = bottom
    while j >= 0 and j != top:
        out.append(j)
        j = parents[j]
    return out[::-1] if j == top else []


def _subtree(children, j) -> list[int]:
    out, stack = [], [j]
    while stack:
        k = stack.pop()
        out.append(k)
        stack.extend(children[k])
    return out


def _seg_dev(pos, chain, a, b) -> float:
    """Summed squared distance of chain joints strictly between indices a and
    b from the segment pos[chain[a]] -> pos[chain[b]]."""
    if b - a < 2:
        return 0.0
    p0, p1 = pos[chain[a]], pos[chain[b]]
    d = p1 - p0
    ll = float(d @ d)
    q = pos[chain[a + 1:b]] - p0
    t = np.clip(q @ d / max(ll, 1e-12), 0.0, 1.0)
    return float(np.sum((q - t[:, None] * d) ** 2))


def _horizontal_bone(pos, chain, a, b, min_len) -> bool:
    """Whether a bone between chain[a] and chain[b] runs more sideways than
    vertical (a foot, a pelvis helper)."""
    for k in range(a, b):
        d = pos[chain[k + 1]] - pos[chain[k]]
        if np.linalg.norm(d) > min_len and abs(d[1]) < np.linalg.norm(d[[0, 2]]):
            return True
    return False


def _pick_leg(pos, chain, floor, scale):
    """(thigh, knee, ankle) chain indices and a cost for one leg chain."""
    best = (np.inf, None)
    n = len(chain)
    for i, j, k in itertools.combinations(range(n), 3):
        l1 = np.linalg.norm(pos[chain[j]] - pos[chain[i]])
        l2 = np.linalg.norm(pos[chain[k]] - pos[chain[j]])
        if l1 < 0.05 * scale or l2 < 0.05 * scale:
            continue
        cost = 4.0 * (np.log(l1 / l2) - 0.03) ** 2
        cost += (_seg_dev(pos, chain, i, j) + _seg_dev(pos, chain, j, k)) / scale ** 2 * 50.0
        cost += 4.0 * ((pos[chain[k], 1] - floor) / scale) ** 2
        if _horizontal_bone(pos, chain, i, k, 0.02 * scale):
            cost += 5.0
        # a helper just above the thigh (Daz's buttock): the thigh is the
        # last joint before the long bone
        if j > i + 1 and np.linalg.norm(pos[chain[i + 1]] - pos[chain[i]]) < 0.06 * (l1 + l2):
            cost += 1.0
        # the thigh is the top of the straight leg: no long drop above it
        if i > 0 and pos[chain[0], 1] - pos[chain[i], 1] > 0.2 * (l1 + l2):
            cost += 2.0
        if cost < best[0]:
            best = (cost, (i, j, k))
    return best[1], best[0]


def _pick_arm(pos, chain, leg_len, children, base, left):
    """(shoulder, elbow, wrist) chain indices and a cost for one arm chain
    branching off the spine joint ``base``."""
    best = (np.inf, None)
    n = len(chain)
    branch = [len(children[m]) > 1 for m in chain]
    for i, j, k in itertools.combinations(range(n), 3):
        l1 = np.linalg.norm(pos[chain[j]] - pos[chain[i]])
        l2 = np.linalg.norm(pos[chain[k]] - pos[chain[j]])
        if l1 < 1e-3 * leg_len or l2 < 1e-3 * leg_len:
            continue
        cost = (np.log(l1 / (0.34 * leg_len))) ** 2 + (np.log(l2 / (0.31 * leg_len))) ** 2
        cost += 0.5 * (np.log(l1 / l2) - 0.1) ** 2
        cost += (_seg_dev(pos, chain, i, j) + _seg_dev(pos, chain, j, k)) / leg_len ** 2 * 20.0
        rest = np.linalg.norm(pos[chain[k:]] - pos[chain[k]], axis=1).max() if k < n - 1 else 0.0
        if rest > 0.35 * leg_len:  # what lies beyond the wrist is a hand
            cost += 3.0
        if any(branch[j + 1:k]):  # the fingers branch at the wrist
            cost += 2.0
        elif not branch[k] and any(branch[k + 1:]):
            cost += 1.5
        if abs((pos[chain[i]] - pos[base]) @ left) < 0.1 * leg_len:  # shoulders are apart
            cost += 1.0
        if cost < best[0]:
            best = (cost, (i, j, k))
    return best[1], best[0]


def _is_end(names, children, top, parent, above_chest) -> bool:
    if children[top]:
        return False
    if parent not in above_chest:
        return False
    n = names[top].lower()
    return any(w in n for w in _END_WORDS) or len(children[parent]) > 1


def structure_roles(names, parents, positions) -> tuple[dict, dict, np.ndarray, np.ndarray, list]:
    """Roles from the hierarchy and the rest positions alone (names unused,
    except to recognise ``...End``/``...Top`` leaves above the head).

    Parameters
    ----------
    names : J joint names.
    parents : (J,) parent indices (-1 for roots), parents before children.
    positions : (J, 3) rest world positions, internal space (Y up).

    Returns
    -------
    (roles {role: joint}, quality {role: 0..1}, left (3,), forward (3,),
    notes [str]).
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    parents = np.asarray(parents, dtype=np.int64)
    n = len(pos)
    notes: list[str] = []
    out: dict[str, int] = {}
    qual: dict[str, float] = {}
    left = np.array([1.0, 0.0, 0.0])
    forward = np.array([0.0, 0.0, 1.0])
    if n < 5:
        return out, qual, left, forward, ["fewer than 5 joints"]
    children = _children(parents)
    y = pos[:, 1]
    height = float(np.ptp(y))
    if height <= 1e-9:
        return out, qual, left, forward, ["flat skeleton (no vertical extent)"]
    floor = float(y.min())
    # lateral axis: principal horizontal direction of the rest pose
    h = pos[:, [0, 2]] - pos[:, [0, 2]].mean(0)
    _, _, vt = np.linalg.svd(h, full_matrices=False)
    lat = np.array([vt[0, 0], 0.0, vt[0, 1]])
    if lat[0] < 0 or (abs(lat[0]) < 1e-9 and lat[2] < 0):
        lat = -lat
    centre = np.median(pos, axis=0)
    side = (pos - centre) @ lat
    low = y < floor + 0.15 * height
    cand_l = np.flatnonzero(low & (side > 0.02 * height))
    cand_r = np.flatnonzero(low & (side < -0.02 * height))
    if not len(cand_l) or not len(cand_r):
        notes.append("no pair of feet (lowest joints on both sides)")
        return out, qual, left, forward, notes
    foot_a = int(cand_l[np.argmin(y[cand_l])])
    foot_b = int(cand_r[np.argmin(y[cand_r])])
    hips = _lca(parents, foot_a, foot_b)
    if hips < 0:
        notes.append("the feet have no common ancestor")
        return out, qual, left, forward, notes
    legs = {}
    for tag, foot in (("a", foot_a), ("b", foot_b)):
        chain = _chain(parents, hips, foot)
        pick, cost = _pick_leg(pos, chain, floor, height)
        if pick is None:
            notes.append("a leg chain has fewer than three usable joints")
            return out, qual, left, forward, notes
        i, j, k = pick
        toe = None
        for m in chain[k + 1:]:
            if np.linalg.norm(pos[m] - pos[chain[k]]) > 0.02 * height:
                toe = m
                break
        legs[tag] = (chain[i], chain[j], chain[k], toe, cost, chain[:i])
    # facing from the toes, left = up x forward
    fw = np.zeros(3)
    for _thigh, _knee, ankle, toe, _, _ in legs.values():
        if toe is not None:
            fw += pos[toe] - pos[ankle]
    fw[1] = 0.0
    if np.linalg.norm(fw) > 1e-3 * height:
        fw /= np.linalg.norm(fw)
        lft = np.cross([0.0, 1.0, 0.0], fw)
        if abs(lft @ lat) > 0.5:  # toes agree with the lateral axis
            forward, left = fw, lft
        else:
            notes.append("toes do not point across the lateral axis: facing +Z assumed")
            forward = np.cross(lat, [0.0, 1.0, 0.0])
            left = lat
    else:
        forward = np.cross(lat, [0.0, 1.0, 0.0])
        left = lat
    if left @ lat < 0:
        legs = {"a": legs["b"], "b": legs["a"]}
    leg_len = []
    for tag, s in (("a", "l"), ("b", "r")):
        thigh, knee, ankle, toe, cost, helpers = legs[tag]
        q = float(np.clip(0.9 - 0.1 * cost, 0.5, 0.9))
        for role, j in (("thigh", thigh), ("shin", knee), ("foot", ankle), ("toe", toe)):
            if j is not None:
                out[f"{role}_{s}"], qual[f"{role}_{s}"] = int(j), q
        leg_len.append(np.linalg.norm(pos[knee] - pos[thigh]) + np.linalg.norm(pos[ankle] - pos[knee]))
    out["hips"], qual["hips"] = int(hips), 0.9
    leg = float(np.mean(leg_len))

    # the chain above the hips to the top joint
    leg_joints = set()
    for tag in ("a", "b"):
        first = _chain(parents, hips, legs[tag][0])[0]
        leg_joints.update(_subtree(children, first))
    above = [j for j in _subtree(children, hips) if j not in leg_joints and j != hips]
    if not above:
        notes.append("nothing above the hips")
        return out, qual, left, forward, notes
    top = int(max(above, key=lambda j: y[j]))
    spine = [hips] + _chain(parents, hips, top)
    on_spine = set(spine)
    # arms: the branches off the spine reaching furthest to each side
    branches = []
    for idx, j in enumerate(spine[1:], 1):
        for c in children[j]:
            if c in on_spine:
                continue
            sub = _subtree(children, c)
            lat_ext = (pos[sub] - pos[hips]) @ left
            branches.append((idx, c, sub, float(lat_ext.max()), float(lat_ext.min())))
    arms = {}
    for s, sign in (("l", 1.0), ("r", -1.0)):
        best = max(branches, key=lambda b: sign * (b[3] if sign > 0 else b[4]), default=None)
        if best is None or sign * (best[3] if sign > 0 else best[4]) < 0.12 * leg:
            notes.append(f"no {'left' if s == 'l' else 'right'} arm (lateral branch off the spine)")
            continue
        idx, c, sub, _, _ = best
        tip = int(max(sub, key=lambda m: np.linalg.norm(pos[m] - pos[spine[idx]])))
        chain = [c] + _chain(parents, c, tip)
        pick, cost = _pick_arm(pos, chain, leg, children, spine[idx], left)
        if pick is None:
            notes.append(f"{'left' if s == 'l' else 'right'} arm chain has fewer than three joints")
            continue
        i, j, k = pick
        q = float(np.clip(0.9 - 0.1 * cost, 0.5, 0.9))
        arms[s] = idx
        out[f"upper_arm_{s}"], out[f"forearm_{s}"], out[f"hand_{s}"] = chain[i], chain[j], chain[k]
        for r in ("upper_arm", "forearm", "hand"):
            qual[f"{r}_{s}"] = q
        if i > 0 and np.linalg.norm(pos[chain[i]] - pos[chain[i - 1]]) > 0.02 * leg:
            out[f"clavicle_{s}"], qual[f"clavicle_{s}"] = chain[i - 1], q
    if arms:
        ci = max(arms.values())
        out["chest"], qual["chest"] = spine[ci], 0.8
        between = spine[1:ci]
        for role, j in zip(("spine_lower", "spine_mid"), between):
            out[role], qual[role] = j, 0.7
        above_chest = spine[ci + 1:]
    else:
        above_chest = spine[1:]
    if above_chest:
        # the head: the first joint above the chest where the face joints
        # (eyes, jaw, a head-top end) branch; else the top, or its parent when
        # the top is an end joint
        branching = [j for j in above_chest if len(children[j]) > 1]
        head = top
        if branching:
            head = branching[0]
        elif len(above_chest) >= 2 and _is_end(names, children, top, parents[top], set(above_chest)):
            head = int(parents[top])
        out["head"], qual["head"] = head, 0.8
        if above_chest[0] != head and "chest" in out:
            out["neck"], qual["neck"] = above_chest[0], 0.7
    else:
        notes.append("no head above the arms")
    return out, qual, left, forward, notes


# --------------------------------------------------------------------------
# names + structure

def find_roles(names, parents, positions, user_roles: dict | None = None) -> RigRoles:
    """Semantic roles of a skeleton from names (hints) and structure.

    Parameters
    ----------
    names : J joint names.
    parents : (J,) parent indices, parents before children.
    positions : (J, 3) rest/bind world positions, internal space (Y up).
    user_roles : {role: joint name} that override both.

    Returns
    -------
    :class:`RigRoles`.
    """
    names = [str(n) for n in names]
    idx = {n: i for i, n in enumerate(names)}
    by_name = {r: idx[n] for r, n in name_roles(names).items()}
    srole, squal, left, forward, notes = structure_roles(names, parents, positions)
    out: dict[str, int] = {}
    conf: dict[str, float] = {}
    how: dict[str, str] = {}
    used_by_name = set(by_name.values())
    for r, j in by_name.items():
        out[r] = j
        if srole.get(r) == j:
            conf[r], how[r] = 1.0, "name+structure"
        elif r in srole:
            conf[r], how[r] = 0.5, "name"
            notes.append(f"{r}: names say {names[j]}, structure says {names[srole[r]]}")
        else:
            conf[r], how[r] = 0.7, "name"
    for r, j in srole.items():
        if r in out or j in used_by_name:
            continue
        out[r], conf[r], how[r] = j, squal[r], "structure"
    for r, n in (user_roles or {}).items():
        if n not in idx:
            raise KeyError(f"joint {n!r} (role {r}) is not in the skeleton")
        out[r], conf[r], how[r] = idx[n], 1.0, "user"
    return RigRoles(names=names, roles=out, confidence=conf, how=how, left=left,
                    forward=forward, notes=notes)


@dataclass
class RigMatch:
    """Pairing of a source skeleton with a target skeleton.

    mapping: :class:`JointMapping` (target name -> source name, ``how``
    per target joint); source, target: their :class:`RigRoles`; missing:
    key roles that could not be paired, {"source": [...], "target": [...]};
    confidence: min over the key roles of the product of both sides'
    confidences (0 when a key role is missing); by_names: True when the
    name tables alone paired every key role (the mapping is then exactly
    :func:`joint_maps.map_joints`'s).
    """
    mapping: JointMapping
    source: RigRoles
    target: RigRoles
    missing: dict
    confidence: float
    by_names: bool

    @property
    def ok(self) -> bool:
        return not (self.missing["source"] or self.missing["target"])

    def index_pairs(self) -> list[tuple[int, int]]:
        """Sorted [(source index, target index)]."""
        si = {n: i for i, n in enumerate(self.source.names)}
        ti = {n: i for i, n in enumerate(self.target.names)}
        return sorted((si[s], ti[t]) for t, s in self.mapping.pairs.items())

    def unpaired_text(self) -> str:
        parts = []
        if self.missing["source"]:
            parts.append("source lacks " + ", ".join(self.missing["source"]))
        if self.missing["target"]:
            parts.append("target lacks " + ", ".join(self.missing["target"]))
        return "; ".join(parts)

    def report(self) -> dict:
        rep = self.mapping.report()
        rep.update({"confidence": round(self.confidence, 3), "by_names": self.by_names,
                    "missing_key_roles": self.missing,
                    "roles": {r: [self.source.joint(r), self.target.joint(r)]
                              for r in sorted(set(self.source.roles) | set(self.target.roles))},
                    "how": dict(self.mapping.how)})
        return rep


def _extend_chains(src_children, tgt_children, pairs_idx: dict[int, int], used_src: set):
    """Pair single unpaired children below paired joints, step by step."""
    stack = list(pairs_idx.items())
    added = {}
    while stack:
        t, s = stack.pop()
        tc = [c for c in tgt_children[t] if c not in pairs_idx and c not in added]
        sc = [c for c in src_children[s] if c not in used_src]
        if len(tgt_children[t]) == 1 and len(src_children[s]) == 1 and len(tc) == 1 and len(sc) == 1:
            added[tc[0]] = sc[0]
            used_src.add(sc[0])
            stack.append((tc[0], sc[0]))
    return added


def match_skeletons(src_names, src_parents, src_positions, tgt_names, tgt_parents, tgt_positions,
                    user_map: dict | None = None, key_roles=KEY_ROLES) -> RigMatch:
    """Pair the joints of a source skeleton (a clip, a reference rig) with a
    target skeleton.

    Parameters
    ----------
    src_names, tgt_names : joint names.
    src_parents, tgt_parents : (Js,), (Jt,) parent indices.
    src_positions, tgt_positions : (Js, 3), (Jt, 3) rest world positions
        (internal space, Y up; units need not agree).
    user_map : {target joint: source joint or None} overriding the automatic
        pairs (see :func:`joint_maps.map_joints`).
    key_roles : roles that must be paired.

    Returns
    -------
    :class:`RigMatch`. When the name tables pair every key role, the mapping
    is :func:`joint_maps.map_joints`'s unchanged; otherwise roles found by
    structure pair the joints, then equal names, then single-child chains.
    """
    src = [str(n) for n in src_names]
    tgt = [str(n) for n in tgt_names]
    sr = find_roles(src, src_parents, src_positions)
    tr = find_roles(tgt, tgt_parents, tgt_positions)
    by_name = map_joints(src, tgt)
    key = [r for r in key_roles]
    covered = all(r in sr.roles and r in tr.roles
                  and by_name.pairs.get(tgt[tr.roles[r]]) == src[sr.roles[r]] for r in key)
    if covered:
        mapping = map_joints(src, tgt, user_map=user_map) if user_map else by_name
    else:
        pairs: dict[int, int] = {}
        how: dict[str, str] = {}
        used: set[int] = set()
        for r in tr.roles:
            if r in sr.roles and sr.roles[r] not in used and tr.roles[r] not in pairs:
                pairs[tr.roles[r]] = sr.roles[r]
                used.add(sr.roles[r])
                how[tgt[tr.roles[r]]] = f"role:{r}"
        sidx = {n: i for i, n in enumerate(src)}
        tidx = {n: i for i, n in enumerate(tgt)}
        for t, s in by_name.pairs.items():
            ti, si = tidx[t], sidx[s]
            if ti not in pairs and si not in used:
                pairs[ti] = si
                used.add(si)
                how[t] = by_name.how.get(t, "name")
        ext = _extend_chains(_children(np.asarray(src_parents)), _children(np.asarray(tgt_parents)),
                             pairs, used)
        for ti, si in ext.items():
            pairs[ti] = si
            how[tgt[ti]] = "chain"
        named = {tgt[t]: src[s] for t, s in sorted(pairs.items())}
        if user_map:
            bad_t = [t for t in user_map if t not in tidx]
            bad_s = [s for s in user_map.values() if s is not None and s not in sidx]
            if bad_t or bad_s:
                raise KeyError("; ".join(m for m in (
                    f"target joints not in the skeleton: {bad_t}" if bad_t else "",
                    f"source joints not in the motion: {bad_s}" if bad_s else "") if m))
            for t, s in user_map.items():
                if s is None:
                    named.pop(t, None)
                    how.pop(t, None)
                    continue
                for other, so in list(named.items()):
                    if so == s and other != t:
                        del named[other]
                        how.pop(other, None)
                named[t] = s
                how[t] = "user"
        named = {t: named[t] for t in tgt if t in named}
        usedn = set(named.values())
        mapping = JointMapping(pairs=named, unmapped_source=[s for s in src if s not in usedn],
                               unmapped_target=[t for t in tgt if t not in named],
                               source_convention=by_name.source_convention,
                               target_convention=by_name.target_convention,
                               how={t: how.get(t, "user") for t in named})
    # key roles paired?
    miss_s = [r for r in key if r not in sr.roles]
    miss_t = [r for r in key if r not in tr.roles]
    if user_map:
        # a user pair covers a role on both sides
        for r in list(miss_s):
            tj = tr.joint(r)
            if tj is not None and mapping.pairs.get(tj):
                miss_s.remove(r)
    conf = 0.0
    if not (miss_s or miss_t):
        conf = float(min(sr.confidence[r] * tr.confidence[r] for r in key)) if key else 1.0
    return RigMatch(mapping=mapping, source=sr, target=tr,
                    missing={"source": miss_s, "target": miss_t},
                    confidence=conf, by_names=bool(covered))


def require_match(match: RigMatch, source_path, target_path, what: str, escape: str) -> None:
    """Raise :class:`InputError` (exit 2) naming the file and the roles when
    key roles are not paired; ``escape`` (appended to the message) says what
    the user can do."""
    if match.ok:
        return
    if match.missing["source"]:
        path, side, roles_ = source_path, "source", match.missing["source"]
    else:
        path, side, roles_ = target_path, "target", match.missing["target"]
    notes = match.source.notes if side == "source" else match.target.notes
    raise InputError(path, f"cannot pair the key joints for {what}: no {', '.join(roles_)} found in "
                           f"this skeleton" + (f" ({'; '.join(notes)})" if notes else "")
                     + f"; {escape}")


def leg_length(roles_: RigRoles, positions) -> float | None:
    """Mean thigh + shin length of both legs (hip -> knee -> ankle) in the
    positions' units, or None without the leg roles.

    Parameters
    ----------
    roles_ : the skeleton's :class:`RigRoles`.
    positions : (J, 3) rest positions.
    """
    pos = np.asarray(positions, dtype=np.float64)
    out = []
    for s in "lr":
        js = [roles_.roles.get(f"{k}_{s}") for k in ("thigh", "shin", "foot")]
        if None in js:
            continue
        out.append(np.linalg.norm(pos[js[1]] - pos[js[0]]) + np.linalg.norm(pos[js[2]] - pos[js[1]]))
    return float(np.mean(out)) if out else None
