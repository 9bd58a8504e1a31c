"""A procedural, parameterised, rigged humanoid (the project's own sample body).

The body is a smooth union of round cones and ellipsoids (:mod:`.implicit`)
laid out around a MakeHuman/Unreal ``game_engine``-style skeleton in an
A-pose (arms 42 degrees below horizontal), meshed with surface nets, relaxed
on the implicit surface, and skinned automatically (each vertex starts on
the bone of its nearest primitive; the one-hot weights are then diffused over
the mesh so joints bend smoothly; top 4 influences, normalised).

Internal space: Y up, metres, facing +Z, character's left = +X, soles on
y = 0. ``BodyParams.height`` is the height of the top of the head.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np
import scipy.sparse as sp

from ...io.usd import triangulate
from ...model import Character, Mesh, Skeleton
from .implicit import Primitive, Solid, best_diagonal, relax_on_surface, sample_grid, surface_nets, vertex_adjacency

REF_HEIGHT = 1.75
SOURCE_PREFIX = "wearfit-samples:body"

#: joint name, parent name (parents precede children)
JOINTS: list[tuple[str, str | None]] = [
    ("Root", None), ("pelvis", "Root"), ("spine_01", "pelvis"), ("spine_02", "spine_01"),
    ("spine_03", "spine_02"), ("neck_01", "spine_03"), ("head", "neck_01"),
    ("clavicle_l", "spine_03"), ("upperarm_l", "clavicle_l"), ("lowerarm_l", "upperarm_l"),
    ("hand_l", "lowerarm_l"),
    ("clavicle_r", "spine_03"), ("upperarm_r", "clavicle_r"), ("lowerarm_r", "upperarm_r"),
    ("hand_r", "lowerarm_r"),
    ("thigh_l", "pelvis"), ("calf_l", "thigh_l"), ("foot_l", "calf_l"), ("ball_l", "foot_l"),
    ("thigh_r", "pelvis"), ("calf_r", "thigh_r"), ("foot_r", "calf_r"), ("ball_r", "foot_r"),
]
JOINT_NAMES = [n for n, _ in JOINTS]
ARM_ANGLE_DEG = 42.0  # A-pose: arms this far below horizontal (MakeHuman-like)


@dataclass(frozen=True)
class BodyParams:
    """Shape parameters (dimensionless factors are relative to the reference).

    height: metres, soles to the top of the head.
    girth: scales torso and limb radii (1 = reference).
    shoulders: scales the shoulder width (clavicle length and chest width).
    hips: scales the hip width (pelvis and leg spacing).
    belly: 0 = flat, 1 = a large round belly (about +11 cm of waist depth).
    bust: 0 = none, 1 = a female bust.
    """
    height: float = REF_HEIGHT
    girth: float = 1.0
    shoulders: float = 1.0
    hips: float = 1.0
    belly: float = 0.0
    bust: float = 0.0

    def to_source(self) -> str:
        return SOURCE_PREFIX + "?" + "&".join(f"{k}={v:g}" for k, v in asdict(self).items())

    @classmethod
    def from_source(cls, source: str) -> BodyParams:
        if not str(source).startswith(SOURCE_PREFIX + "?"):
            raise ValueError(f"{source!r} is not a wearfit sample body")
        kv = dict(part.split("=") for part in source.split("?", 1)[1].split("&"))
        names = {f.name for f in fields(cls)}
        return cls(**{k: float(v) for k, v in kv.items() if k in names})


#: the reference body and the targets
PRESETS: dict[str, BodyParams] = {
    "reference": BodyParams(),
    "tall_thin": BodyParams(height=1.92, girth=0.82, shoulders=0.95, hips=0.92),
    "short_heavy": BodyParams(height=1.58, girth=1.22, shoulders=1.05, hips=1.18, belly=1.0),
    "broad_shoulders": BodyParams(height=1.80, girth=1.08, shoulders=1.25, hips=0.95),
    "curvy_remeshed": BodyParams(height=1.66, girth=0.97, shoulders=0.9, hips=1.2, bust=1.0),
}
#: targets sharing the reference topology (vertex-for-vertex)
SAME_TOPOLOGY_TARGETS = ["tall_thin", "short_heavy", "broad_shoulders"]
#: targets meshed independently (another grid resolution)
REMESHED_TARGETS = {"curvy_remeshed": 0.017}
DEFAULT_RESOLUTION = 0.014


# --------------------------------------------------------------------------
# layout: joints, landmarks and primitives from parameters

def _frame(y_axis, z_ref=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Rows x, y, z of an orthonormal frame whose y is ``y_axis``."""
    y = np.asarray(y_axis, float)
    y = y / np.linalg.norm(y)
    z0 = np.asarray(z_ref, float)
    x = np.cross(y, z0)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(y, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    return np.stack([x, y, z])


@dataclass
class BodyLayout:
    params: BodyParams
    joints: dict            # name -> (3,) bind position
    tips: dict              # name -> (3,) end of the bone (for frames and weights)
    landmarks: dict         # named points/values used by the items
    solid: Solid


def layout(params: BodyParams | None = None) -> BodyLayout:
    """Joint positions, landmarks and the implicit solid for ``params``."""
    P = params or BodyParams()
    s = P.height / REF_HEIGHT
    g = P.girth
    sh = P.shoulders
    hp = P.hips

    def v(x, y, z):
        return np.array([x, y, z], float) * s

    J = {}
    J["Root"] = np.zeros(3)
    J["pelvis"] = v(0, 0.95, -0.005)
    J["spine_01"] = v(0, 1.03, -0.01)
    J["spine_02"] = v(0, 1.13, -0.015)
    J["spine_03"] = v(0, 1.25, -0.02)
    J["neck_01"] = v(0, 1.46, -0.025)
    J["head"] = v(0, 1.56, -0.005)
    tips = {"head": v(0, REF_HEIGHT, 0.0)}
    arm_dir = np.array([np.cos(np.radians(ARM_ANGLE_DEG)), -np.sin(np.radians(ARM_ANGLE_DEG)), 0])
    upper, fore, hand = 0.29 * s, 0.255 * s, 0.19 * s
    for side, sx in (("l", 1.0), ("r", -1.0)):
        d = arm_dir * [sx, 1, 1]
        J[f"clavicle_{side}"] = v(sx * 0.02, 1.425, -0.01)
        # heavier bodies carry their arms farther out (keeps the armpit open)
        J[f"upperarm_{side}"] = v(sx * (0.17 * sh + 0.15 * (g - 1.0)), 1.405, -0.03)
        J[f"lowerarm_{side}"] = J[f"upperarm_{side}"] + upper * d
        J[f"hand_{side}"] = J[f"lowerarm_{side}"] + fore * d
        tips[f"hand_{side}"] = J[f"hand_{side}"] + hand * d
        hx = sx * 0.092 * hp
        J[f"thigh_{side}"] = v(hx / s, 0.92, 0.0)
        J[f"calf_{side}"] = v(hx / s + sx * 0.012, 0.505, 0.012)
        J[f"foot_{side}"] = v(hx / s + sx * 0.022, 0.085, -0.025)
        J[f"ball_{side}"] = v(hx / s + sx * 0.03, 0.025, 0.115)
        tips[f"ball_{side}"] = v(hx / s + sx * 0.034, 0.02, 0.185)

    prims: list[Primitive] = []

    def cone(a, b, ra, rb, bone, scale=(1, 1, 1), frame=None, blend=None):
        a = np.asarray(a, float)
        b = np.asarray(b, float)
        if frame is None:
            axis = b - a
            frame = _frame(axis if np.linalg.norm(axis) > 1e-9 else [0, 1, 0])
        prims.append(Primitive(a, b, float(ra), float(rb), bone, np.asarray(frame, float),
                               np.asarray(scale, float), blend))

    # torso: stacked round cones with elliptical sections, one per spine bone
    gw = g ** -0.35  # girth grows the torso more in depth than in width
    wx = lambda k: (1.0 + k * (hp - 1.0)) * gw  # noqa: E731  hip influence fading up the torso
    qx = lambda k: (1.0 + k * (sh - 1.0)) * gw  # noqa: E731  shoulder influence
    cone(v(0, 0.885, -0.01), v(0, 1.03, -0.012), 0.102 * g, 0.092 * g, "pelvis",
         scale=(1.62 * wx(1.0), 1, 1.0))
    cone(v(0, 1.03, -0.012), v(0, 1.13, -0.016), 0.092 * g, 0.094 * g, "spine_01",
         scale=(1.45 * wx(0.5), 1, 1.0))
    cone(v(0, 1.13, -0.016), v(0, 1.25, -0.02), 0.094 * g, 0.106 * g, "spine_02",
         scale=(1.45 * qx(0.3), 1, 1.0))
    cone(v(0, 1.25, -0.02), v(0, 1.375, -0.03), 0.106 * g, 0.085 * g, "spine_03",
         scale=(1.52 * qx(0.6), 1, 1.0))
    # glutes
    for sx in (1, -1):
        cone(v(sx * 0.07 * hp, 0.90, -0.055), v(sx * 0.07 * hp, 0.90, -0.055), 0.075 * g,
             0.075 * g, "pelvis", scale=(1, 1.1, 0.9))
    if P.belly > 0:
        b = P.belly
        cone(v(0, 1.09, 0.0 + 0.02 * b), v(0, 1.09, 0.0 + 0.02 * b), 0.11 * g * (0.8 + 0.2 * b),
             0.0, "spine_01", scale=(1.15, 1.0, 0.75 + 0.35 * b))
    if P.bust > 0:
        for sx in (1, -1):
            c = v(sx * 0.085 * qx(1.0), 1.29, 0.055)
            cone(c, c, 0.055 * P.bust * g, 0.0, "spine_03", scale=(1.0, 1.0, 0.9))
    # shoulder yoke (clavicles), neck, head
    for side, sx in (("l", 1.0), ("r", -1.0)):
        cone(v(sx * 0.03, 1.385, -0.03), J[f"upperarm_{side}"] + v(-sx * 0.01, -0.005, 0),
             0.06 * g, 0.052 * g, f"clavicle_{side}")
    cone(v(0, 1.37, -0.03), v(0, 1.545, -0.01), 0.058 * g, 0.05 * g, "neck_01")
    head_c = v(0, 1.635, 0.008)
    head_r = np.array([0.077, 0.115, 0.098]) * s
    cone(head_c, head_c, head_r[0], 0.0, "head", scale=head_r / head_r[0])
    cone(v(0, 1.6, 0.03), v(0, 1.545, 0.062), 0.05 * s, 0.03 * s, "head")  # jaw
    cone(v(0, 1.645, 0.098), v(0, 1.612, 0.112), 0.013 * s, 0.014 * s, "head", blend=0.012)  # nose
    # arms: deltoid, upper arm, forearm, hand (flat mitt) and thumb
    for side in ("l", "r"):
        sa, el, wr = J[f"upperarm_{side}"], J[f"lowerarm_{side}"], J[f"hand_{side}"]
        d = (wr - el) / np.linalg.norm(wr - el)
        cone(sa, sa, 0.056 * g * s, 0.0, f"upperarm_{side}", scale=(1.0, 1.0, 0.95))
        cone(sa, el, 0.048 * g * s, 0.038 * g * s, f"upperarm_{side}")
        cone(el, wr, 0.037 * g * s, 0.026 * g * s, f"lowerarm_{side}")
        # hand frame: y along the arm, x = palm normal (in the arm's vertical plane)
        fr = _frame(d, (0, 0, 1))
        tip = tips[f"hand_{side}"]
        cone(wr + 0.012 * s * d, wr + 0.09 * s * d, 0.022 * s, 0.024 * s, f"hand_{side}",
             scale=(0.72, 1.0, 1.75), frame=fr, blend=0.015)
        cone(wr + 0.09 * s * d, tip - 0.017 * s * d, 0.021 * s, 0.017 * s, f"hand_{side}",
             scale=(0.8, 1.0, 1.45), frame=fr, blend=0.015)
        th0 = wr + 0.03 * s * d + v(0, 0, 0.025)
        th1 = th0 + 0.05 * s * d + v(0, 0, 0.03)
        cone(th0, th1, 0.014 * s, 0.011 * s, f"hand_{side}", blend=0.015)
    # legs: thigh, calf (+ muscle), foot (heel to ball, flattened), toes
    for side in ("l", "r"):
        hip, knee, ank, ball = (J[f"thigh_{side}"], J[f"calf_{side}"], J[f"foot_{side}"],
                                J[f"ball_{side}"])
        cone(hip + v(0, 0.02, 0), knee, 0.088 * g * s, 0.054 * g * s, f"thigh_{side}")
        cone(knee, ank, 0.052 * g * s, 0.034 * g * s, f"calf_{side}")
        mid = knee + 0.3 * (ank - knee) + v(0, 0, -0.018)
        cone(mid, mid, 0.05 * g * s, 0.0, f"calf_{side}", scale=(0.95, 2.0, 0.95))
        heel = np.array([ank[0], 0.041 * s, ank[2] - 0.03 * s])
        toe_base = np.array([ball[0], 0.031 * s, ball[2]])
        fr = _frame(toe_base - heel, (0, 1, 0))
        cone(heel, toe_base, 0.041 * s, 0.031 * s, f"foot_{side}", scale=(1.2, 1, 1), frame=fr,
             blend=0.015)
        cone(ank + v(0, 0.01, 0), heel + v(0, 0.01, 0.03), 0.035 * s, 0.036 * s, f"foot_{side}",
             blend=0.02)
        toe_tip = tips[f"ball_{side}"]
        toe_tip = np.array([toe_tip[0], 0.022 * s, toe_tip[2]])
        fr2 = _frame(toe_tip - toe_base, (0, 1, 0))
        cone(toe_base, toe_tip, 0.03 * s, 0.021 * s, f"ball_{side}", scale=(1.25, 1, 1),
             frame=fr2, blend=0.015)

    # bone tips for the frames
    tips.setdefault("Root", J["pelvis"])
    tips["pelvis"] = J["spine_01"]
    tips["spine_01"] = J["spine_02"]
    tips["spine_02"] = J["spine_03"]
    tips["spine_03"] = J["neck_01"]
    tips["neck_01"] = J["head"]
    for side in "lr":
        tips[f"clavicle_{side}"] = J[f"upperarm_{side}"]
        tips[f"upperarm_{side}"] = J[f"lowerarm_{side}"]
        tips[f"lowerarm_{side}"] = J[f"hand_{side}"]
        tips[f"thigh_{side}"] = J[f"calf_{side}"]
        tips[f"calf_{side}"] = J[f"foot_{side}"]
        tips[f"foot_{side}"] = J[f"ball_{side}"]

    L = {
        "height": P.height,
        "head_center": head_c, "head_radii": head_r,
        "eye_l": v(0.032, 1.648, 0.092), "eye_r": v(-0.032, 1.648, 0.092),
        "waist_y": 1.07 * s, "hip_y": 0.90 * s, "crotch_y": 0.84 * s,
        "neck_base_y": 1.43 * s, "chest_y": 1.30 * s,
        "knee_y": J["calf_l"][1], "ankle_y": J["foot_l"][1],
        "arm_dir_l": arm_dir, "arm_dir_r": arm_dir * [-1, 1, 1],
        "scale": s,
    }
    return BodyLayout(P, J, tips, L, Solid(prims, blend=0.028 * s, band=0.06))


# --------------------------------------------------------------------------
# skeleton and skin weights

def build_skeleton(lay: BodyLayout) -> Skeleton:
    """Bone-aligned bind frames (y along the bone, like Blender/MakeHuman),
    Root at the origin with the identity."""
    names = JOINT_NAMES
    parents = np.array([-1 if p is None else names.index(p) for _, p in JOINTS], dtype=np.int64)
    bind = np.tile(np.eye(4), (len(names), 1, 1))
    for j, n in enumerate(names):
        if n != "Root":
            axis = lay.tips[n] - lay.joints[n]
            zref = (0, 1, 0) if n.startswith(("foot", "ball")) else (0, 0, 1)
            bind[j, :3, :3] = _frame(axis, zref)
        bind[j, 3, :3] = lay.joints[n]
    paths = []
    for j, n in enumerate(names):
        paths.append(n if parents[j] < 0 else f"{paths[parents[j]]}/{n}")
    sk = Skeleton(joint_names=list(names), joint_paths=paths, parents=parents, bind_world=bind,
                  rest_local=np.tile(np.eye(4), (len(names), 1, 1)), skel_to_world=np.eye(4),
                  path="/Root/Character/Skeleton")
    sk.rest_local = sk.local_from_world(bind)
    return sk


def skin_weights(lay: BodyLayout, points: np.ndarray, quads: np.ndarray, k: int = 4,
                 diffuse: int = 22):
    """(N, k) joint indices and weights: one-hot on the bone of the nearest
    primitive, diffused over the mesh ``diffuse`` times, top ``k`` kept."""
    lab = lay.solid.labels(points)
    bone_of_prim = np.array([JOINT_NAMES.index(b) for b in lay.solid.bones()])
    n = len(points)
    w = sp.coo_matrix((np.ones(n), (np.arange(n), bone_of_prim[lab])),
                      shape=(n, len(JOINT_NAMES))).toarray()
    adj = vertex_adjacency(n, quads)
    for _ in range(diffuse):
        w = 0.5 * w + 0.5 * (adj @ w)
    idx = np.argsort(-w, axis=1)[:, :k]
    ww = np.take_along_axis(w, idx, axis=1)
    ww[ww < 1e-3] = 0.0
    ww /= ww.sum(axis=1, keepdims=True)
    return idx.astype(np.int64), ww


# --------------------------------------------------------------------------
# meshing

def mesh_solid(solid: Solid, resolution: float, relax_iters: int = 4):
    """Mesh a solid: surface nets on a grid of ``resolution`` metres, then
    projection onto f = 0 and relaxation. Returns points (N, 3), quads (Q, 4)."""
    # the solid's bounds plus a few cells;
    # an irrational grid offset keeps symmetric features off grid diagonals
    lo = np.min([p.bounds(0.0)[0] for p in solid.primitives], axis=0) - (3 + 0.318) * resolution
    hi = np.max([p.bounds(0.0)[1] for p in solid.primitives], axis=0) + 3 * resolution
    vals, origin, h = sample_grid(solid, lo, hi, resolution)
    pts, quads = surface_nets(vals, origin, h)
    pts = solid.project(pts, 0.0, iters=4)
    pts = relax_on_surface(solid, pts, quads, 0.0, iters=relax_iters)
    quads = best_diagonal(pts, quads)
    return pts, quads


def _character(lay: BodyLayout, points: np.ndarray, quads: np.ndarray, name: str,
               weights=None) -> Character:
    counts = np.full(len(quads), 4, dtype=np.int64)
    fvi = quads.ravel().astype(np.int64)
    faces, t2p = triangulate(counts, fvi)
    if weights is None:
        weights = skin_weights(lay, points, quads)
    idx, w = weights
    mesh = Mesh(name="Body", points=points, faces=faces, face_vertex_counts=counts,
                face_vertex_indices=fvi, tri_to_poly=t2p, path="/Root/Character/Body",
                joint_indices=idx, joint_weights=w,
                display_color=np.array([0.8, 0.64, 0.53]))
    return Character(source=lay.params.to_source() + f"#{name}", up_axis="Y",
                     meters_per_unit=1.0, to_internal=np.eye(4), skeleton=build_skeleton(lay),
                     body=mesh, items=[], time_codes_per_second=30.0,
                     skel_root_path="/Root/Character")


def make_body(params: BodyParams | str | None = None,
              resolution: float = DEFAULT_RESOLUTION) -> Character:
    """A rigged sample body meshed from scratch.

    params: :class:`BodyParams`, a preset name or None (the reference).
    resolution: grid step in metres (0.0115 gives about 11k vertices).
    Returns a :class:`Character` in internal space whose skeleton's bind pose
    reproduces the mesh exactly (``skin_mesh(body, skel, skel.bind_world)``).
    """
    name = params if isinstance(params, str) else "custom"
    if isinstance(params, str):
        params = PRESETS[params]
    lay = layout(params)
    pts, quads = mesh_solid(lay.solid, resolution)
    return _character(lay, pts, quads, name)


def body_params(character: Character) -> BodyParams:
    """The parameters a sample body was made from (from its ``source``)."""
    return BodyParams.from_source(character.source.split("#", 1)[0])


def morph_body(reference: Character, params: BodyParams | str, relax_iters: int = 3) -> Character:
    """A target body with the reference's topology (vertex for vertex).

    Each reference vertex is carried by its skin weights through per-bone
    affine maps (reference bone -> target bone: translation, bone length
    scale and radius scale), then projected onto the target's implicit
    surface and relaxed there. Faces and skin weights are shared.
    """
    name = params if isinstance(params, str) else "custom"
    if isinstance(params, str):
        params = PRESETS[params]
    ref_lay = layout(body_params(reference))
    tgt_lay = layout(params)
    ref_sk = build_skeleton(ref_lay)
    tgt_sk = build_skeleton(tgt_lay)
    first_r = {}
    first_t = {}
    for pr in ref_lay.solid.primitives:
        first_r.setdefault(pr.bone, pr)
    for pr in tgt_lay.solid.primitives:
        first_t.setdefault(pr.bone, pr)
    rs = {b: (first_t[b].ra + first_t[b].rb) * first_t[b].scale
          / max(1e-9, first_r[b].ra + first_r[b].rb) / first_r[b].scale for b in first_r}
    mats = np.tile(np.eye(4), (len(JOINT_NAMES), 1, 1))
    for j, n in enumerate(JOINT_NAMES):
        if n == "Root":
            continue
        len_r = np.linalg.norm(ref_lay.tips[n] - ref_lay.joints[n])
        len_t = np.linalg.norm(tgt_lay.tips[n] - tgt_lay.joints[n])
        ratio = rs.get(n, np.ones(3))
        sc = np.array([ratio[0], len_t / len_r, ratio[2]])
        # bone frame axes are close to the primitive frames for the main primitives
        local = np.diag(np.append(sc, 1.0))
        mats[j] = np.linalg.inv(ref_sk.bind_world[j]) @ local @ tgt_sk.bind_world[j]
    mats[0] = tgt_sk.bind_world[0] @ np.linalg.inv(ref_sk.bind_world[0])
    body = reference.body
    ph = np.concatenate([body.points, np.ones((body.n_points, 1))], axis=1)
    blended = np.einsum("nk,nkij->nij", body.joint_weights, mats[body.joint_indices])
    pts = np.einsum("ni,nij->nj", ph, blended)[:, :3]
    pts = tgt_lay.solid.project(pts, 0.0, iters=5)
    quads = body.face_vertex_indices.reshape(-1, 4)
    pts = relax_on_surface(tgt_lay.solid, pts, quads, 0.0, iters=relax_iters)
    return _character(tgt_lay, pts, quads, name, weights=(body.joint_indices.copy(),
                                                          body.joint_weights.copy()))
