"""glTF edge: read ``.glb``/``.gltf`` characters into the numpy model.

:func:`read_gltf_character` returns a :class:`wearfit_usd.model.Character`
like :func:`wearfit_usd.io.usd.read_character` does for a USD stage: the
skinned mesh with most points is the body (its skin's joints are the
skeleton), every other mesh an item (skinned when its skin's joints are all
skeleton joints). glTF's space is the internal one (metres, Y up, +Z
forward): ``to_internal`` is the identity, ``up_axis`` ``"Y"``,
``meters_per_unit`` 1.

glTF matrices are column-major and act on column vectors; read as row-major
(16,) -> (4, 4) they are the row-vector matrices of :mod:`wearfit_usd.transforms`.
Skinning (glTF 2.0, 3.7.3): ``p' = sum_k w_k [p, 1] @ IBM[j_k] @ world[j_k]``;
the skinned mesh node's own transform is ignored. The *bind pose* is the
inverse of the inverse bind matrices placed by the body mesh node's
transform (what an unskinned viewer shows), the *nodes pose* the node
transforms as stored. Assets whose bind pose is splayed (a T-pose in the
IBMs, another pose in the nodes, or the reverse) are read in the pose asked
for (``pose``): ``bind``, ``nodes``, the first frame of a named animation,
or ``auto``: of bind and nodes, the one whose arms and legs are closest to
the dev references' rest pose (upper arms ~42 degrees from hanging down,
thighs ~8 degrees), said in a line.

Primitives of one mesh are merged (per-primitive materials become a
``uniform`` ``displayColor`` primvar when they differ); ``TEXCOORD_0/1``
become ``st``/``st1`` (V flipped to USD's bottom-left origin);
``JOINTS_0/WEIGHTS_0`` and ``_1`` give up to 8 influences. ``pygltflib`` is
imported when a function runs.
"""
from __future__ import annotations

import base64
import re
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from ..errors import GeometryError, InputError
from ..model import Character, Mesh, Primvar, Skeleton
from ..motion.rig_match import find_roles
from ..progress import info
from ..transforms import invert, matrix_from_quat

GLTF_SUFFIXES = (".glb", ".gltf")
POSES = ("auto", "bind", "nodes")
#: the dev references' rest pose (MakeHuman A-pose): degrees from hanging straight down
REFERENCE_ARM_DEG = 42.0
REFERENCE_LEG_DEG = 8.0

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
              5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_NORM_DIV = {np.int8: 127.0, np.uint8: 255.0, np.int16: 32767.0, np.uint16: 65535.0}

_default_pose = "auto"


def set_default_pose(pose: str | None) -> None:
    """The pose used when a reader call names none (the CLI's ``--gltf-pose``)."""
    global _default_pose
    _default_pose = pose or "auto"


def is_gltf(path) -> bool:
    return Path(path).suffix.lower() in GLTF_SUFFIXES


def joint_token(name: str) -> str:
    """A glTF node name made a USD joint token element (other characters ->
    ``_``, no leading digit), as Blender's USD exporter spells them."""
    s = re.sub(r"[^A-Za-z0-9_]", "_", name or "joint")
    return s if s and not s[0].isdigit() else f"_{s}"


# --------------------------------------------------------------------------
# document and accessors

class GltfDocument:
    """A loaded glTF: the ``pygltflib.GLTF2`` object, its buffers as bytes,
    node parents and local matrices (row-vector form)."""

    def __init__(self, path):
        import pygltflib
        self.path = Path(path)
        if not self.path.exists():
            raise InputError(path, "file not found")
        if self.path.is_dir():
            raise InputError(path, "is a folder, not a file")
        raw = self.path.read_bytes()
        try:
            if raw[:4] == b"glTF":
                g = pygltflib.GLTF2.load_from_bytes(raw)
            elif self.path.suffix.lower() == ".glb":
                raise ValueError("no glTF binary header")
            else:
                g = pygltflib.GLTF2.from_json(raw.decode("utf-8"))
        except Exception as exc:
            why = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
            raise InputError(path, f"cannot read as glTF 2.0: {why[:200]}") from None
        if g.asset is None or not str(g.asset.version or "").startswith("2"):
            raise InputError(path, f"not glTF 2.0 (asset version {getattr(g.asset, 'version', None)!r})")
        self.g = g
        self.buffers = [self._buffer(i, b) for i, b in enumerate(g.buffers or [])]
        self.parent = np.full(len(g.nodes or []), -1, dtype=np.int64)
        for i, n in enumerate(g.nodes or []):
            for c in n.children or []:
                if not 0 <= c < len(g.nodes):
                    raise InputError(path, f"node {i} names a child {c} that does not exist")
                self.parent[c] = i
        self.local = np.array([node_matrix(n) for n in g.nodes or []]).reshape(-1, 4, 4)

    def _buffer(self, i, buf) -> bytes:
        if buf.uri is None:
            blob = self.g.binary_blob()
            if blob is None:
                raise InputError(self.path, f"buffer {i} has no data (no GLB binary chunk)")
            return bytes(blob)
        if buf.uri.startswith("data:"):
            return base64.b64decode(buf.uri.split(",", 1)[1])
        f = self.path.parent / unquote(buf.uri)
        if not f.exists():
            raise InputError(self.path, f"buffer {i}: file {buf.uri} not found beside it")
        return f.read_bytes()

    def accessor(self, index: int) -> np.ndarray:
        """(count, components) array of accessor ``index`` (normalised
        integers as floats in [0, 1] / [-1, 1]; sparse values applied)."""
        g = self.g
        if index is None or not 0 <= index < len(g.accessors or []):
            raise InputError(self.path, f"accessor {index} does not exist")
        a = g.accessors[index]
        dt = np.dtype(_COMPONENT[a.componentType])
        n = _NCOMP[a.type]
        if a.bufferView is None:
            arr = np.zeros((a.count, n), dtype=dt)
        else:
            arr = self._view(a.bufferView, a.byteOffset or 0, a.count, dt, n)
        if a.sparse is not None and a.sparse.count:
            s = a.sparse
            idx = self._view(s.indices.bufferView, s.indices.byteOffset or 0, s.count,
                             np.dtype(_COMPONENT[s.indices.componentType]), 1)[:, 0].astype(np.int64)
            vals = self._view(s.values.bufferView, s.values.byteOffset or 0, s.count, dt, n)
            arr = arr.copy()
            arr[idx] = vals
        if a.normalized and dt.type in _NORM_DIV:
            return np.maximum(arr.astype(np.float64) / _NORM_DIV[dt.type], -1.0)
        return arr

    def _view(self, view_index, offset, count, dt, n) -> np.ndarray:
        bv = self.g.bufferViews[view_index]
        data = self.buffers[bv.buffer]
        stride = bv.byteStride or dt.itemsize * n
        start = (bv.byteOffset or 0) + offset
        need = start + (count - 1) * stride + dt.itemsize * n if count else start
        if need > len(data):
            raise InputError(self.path, f"bufferView {view_index} reads past the end of buffer {bv.buffer}")
        return np.ndarray((count, n), dtype=dt, buffer=data, offset=start,
                          strides=(stride, dt.itemsize)).copy()

    def world(self, local: np.ndarray | None = None) -> np.ndarray:
        """(nodes, 4, 4) scene-space node matrices from (nodes, 4, 4) locals
        (default: as stored)."""
        local = self.local if local is None else local
        out = np.empty_like(local)
        done = np.zeros(len(local), dtype=bool)
        for i in range(len(local)):
            chain = []
            j = i
            while j >= 0 and not done[j]:
                chain.append(j)
                j = self.parent[j]
                if len(chain) > len(local):
                    raise InputError(self.path, "the node hierarchy has a cycle")
            for k in reversed(chain):
                p = self.parent[k]
                out[k] = local[k] if p < 0 else local[k] @ out[p]
                done[k] = True
        return out

    def animation_first_frame(self, name: str) -> np.ndarray:
        """Node locals with animation ``name`` applied at its first key time."""
        anims = self.g.animations or []
        match = [a for a in anims if a.name == name]
        if not match:
            raise InputError(self.path, f"no animation named {name!r}; poses: {', '.join(POSES)}"
                                        + (f", or one of the animations {[a.name for a in anims]}" if anims else ""))
        anim = match[0]
        t0 = min(float(self.accessor(anim.samplers[c.sampler].input).min()) for c in anim.channels)
        trs = {i: list(node_trs(n)) for i, n in enumerate(self.g.nodes)}
        for ch in anim.channels:
            node = ch.target.node
            if node is None or ch.target.path not in ("translation", "rotation", "scale"):
                continue
            s = anim.samplers[ch.sampler]
            times = self.accessor(s.input)[:, 0].astype(np.float64)
            vals = self.accessor(s.output).astype(np.float64)
            if s.interpolation == "CUBICSPLINE":
                vals = vals.reshape(len(times), 3, -1)[:, 1]
            k = int(np.searchsorted(times, t0, side="right") - 1) if t0 >= times[0] else 0
            trs[node]["translation rotation scale".split().index(ch.target.path)] = vals[max(k, 0)]
        local = self.local.copy()
        for i, (t, r, s) in trs.items():
            if self.g.nodes[i].matrix is None:
                local[i] = trs_matrix(t, r, s)
        return local


class AnimationSampler:
    """Evaluates one glTF animation: node locals (row-vector (nodes, 4, 4))
    and morph weights {node: (targets,)} at a time in seconds (LINEAR with
    rotation slerp, STEP, CUBICSPLINE at its key values; clamped outside the
    keys)."""

    def __init__(self, doc: GltfDocument, index: int):
        self.doc = doc
        anim = doc.g.animations[index]
        self.name = anim.name or f"animation_{index}"
        self.tracks = []
        lo, hi = np.inf, -np.inf
        for ch in anim.channels:
            if ch.target.node is None or ch.target.path not in ("translation", "rotation", "scale", "weights"):
                continue
            smp = anim.samplers[ch.sampler]
            times = doc.accessor(smp.input)[:, 0].astype(np.float64)
            vals = doc.accessor(smp.output).astype(np.float64)
            if smp.interpolation == "CUBICSPLINE":
                vals = vals.reshape(len(times), 3, -1)[:, 1]
            else:
                vals = vals.reshape(len(times), -1)
            self.tracks.append((ch.target.node, ch.target.path, times, vals, smp.interpolation or "LINEAR"))
            lo, hi = min(lo, times[0]), max(hi, times[-1])
        self.start, self.end = (0.0, 0.0) if not self.tracks else (float(lo), float(hi))

    def at(self, t: float):
        from ..transforms import quat_slerp
        trs = {}
        weights = {}
        for node, path, times, vals, interp in self.tracks:
            k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 1))
            if interp == "STEP" or k == len(times) - 1 or t <= times[0]:
                v = vals[k] if t > times[0] else vals[0]
            else:
                a = (t - times[k]) / max(times[k + 1] - times[k], 1e-12)
                if path == "rotation":
                    q0, q1 = vals[k][[3, 0, 1, 2]], vals[k + 1][[3, 0, 1, 2]]
                    v = quat_slerp(q0, q1, a)[[1, 2, 3, 0]]
                else:
                    v = (1 - a) * vals[k] + a * vals[k + 1]
            if path == "weights":
                weights[node] = v
            else:
                trs.setdefault(node, list(node_trs(self.doc.g.nodes[node])))[
                    ("translation", "rotation", "scale").index(path)] = v
        local = self.doc.local.copy()
        for node, (tr, r, sc) in trs.items():
            local[node] = trs_matrix(tr, r, sc)
        return local, weights


def node_trs(node):
    """(translation (3,), rotation xyzw (4,), scale (3,)) of a node (defaults filled)."""
    t = np.array(node.translation if node.translation is not None else [0.0, 0.0, 0.0], dtype=float)
    r = np.array(node.rotation if node.rotation is not None else [0.0, 0.0, 0.0, 1.0], dtype=float)
    s = np.array(node.scale if node.scale is not None else [1.0, 1.0, 1.0], dtype=float)
    return t, r, s


def trs_matrix(t, r, s) -> np.ndarray:
    """Row-vector (4, 4) of glTF TRS: scale, then rotation (x, y, z, w), then translation."""
    m = np.eye(4)
    r = np.asarray(r, dtype=float)
    m[:3, :3] = np.diag(np.asarray(s, dtype=float)) @ matrix_from_quat(np.array([r[3], r[0], r[1], r[2]]))
    m[3, :3] = t
    return m


def node_matrix(node) -> np.ndarray:
    """Row-vector (4, 4) local matrix of a glTF node."""
    if node.matrix is not None:
        return np.array(node.matrix, dtype=float).reshape(4, 4)
    return trs_matrix(*node_trs(node))


def animation_names(path) -> list[str]:
    """Names of a glTF file's animations (``animation_<i>`` for unnamed ones)."""
    g = GltfDocument(path).g
    return [a.name or f"animation_{i}" for i, a in enumerate(g.animations or [])]


# --------------------------------------------------------------------------
# meshes

def _material_color(doc: GltfDocument, material) -> np.ndarray | None:
    if material is None or not doc.g.materials or not 0 <= material < len(doc.g.materials):
        return None
    pbr = doc.g.materials[material].pbrMetallicRoughness
    f = pbr.baseColorFactor if pbr is not None and pbr.baseColorFactor is not None else [1, 1, 1, 1]
    return np.array(f[:3], dtype=float)


def _primitive_faces(doc, prim, n) -> np.ndarray | None:
    idx = (np.arange(n, dtype=np.int64) if prim.indices is None
           else doc.accessor(prim.indices)[:, 0].astype(np.int64))
    mode = 4 if prim.mode is None else prim.mode
    if mode == 4:
        f = idx[: len(idx) // 3 * 3].reshape(-1, 3)
    elif mode == 5:  # strip: alternate winding
        k = np.arange(max(len(idx) - 2, 0))
        f = np.stack([idx[k], idx[k + 1 + (k % 2)], idx[k + 2 - (k % 2)]], axis=1)
    elif mode == 6:  # fan
        k = np.arange(1, max(len(idx) - 1, 1))
        f = np.stack([np.full(len(k), idx[0]), idx[k], idx[k + 1]], axis=1)
    else:
        return None  # points and lines: nothing to fit or dress
    if len(f) and (f.min() < 0 or f.max() >= n):
        raise GeometryError(doc.path, "a primitive's index is out of range of its vertices")
    return f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]


class _RawMesh:
    """A glTF mesh node's primitives merged (mesh-space points)."""

    def __init__(self, doc: GltfDocument, node_index: int):
        node = doc.g.nodes[node_index]
        gm = doc.g.meshes[node.mesh]
        self.node = node_index
        self.name = joint_token(node.name or gm.name or f"mesh_{node.mesh}")
        pts, faces, joints, weights, uv0, uv1, tri_color, targets = [], [], [], [], [], [], [], []
        offset = 0
        skinned = node.skin is not None
        shared = {}  # primitives over the same vertex attributes (one per material): their vertices once
        for prim in gm.primitives:
            a = prim.attributes
            if a.POSITION is None:
                continue
            key = (a.POSITION, a.TEXCOORD_0, getattr(a, "TEXCOORD_1", None), a.JOINTS_0, a.WEIGHTS_0,
                   str(prim.targets or []))
            p = doc.accessor(a.POSITION).astype(np.float64)
            f = _primitive_faces(doc, prim, len(p))
            if f is None or len(f) == 0:
                continue
            c = _material_color(doc, prim.material)
            if key in shared:
                faces.append(f + shared[key])
                tri_color.append(np.tile(c if c is not None else [np.nan] * 3, (len(f), 1)))
                continue
            shared[key] = offset
            tg = [np.zeros_like(p) if t.get("POSITION") is None else doc.accessor(t["POSITION"]).astype(np.float64)
                  for t in (prim.targets or [])]
            targets.append(np.array(tg).reshape(len(tg), len(p), 3))
            pts.append(p)
            faces.append(f + offset)
            offset += len(p)
            for src, dst in ((a.TEXCOORD_0, uv0), (a.TEXCOORD_1, uv1)):
                dst.append(None if src is None else doc.accessor(src).astype(np.float64))
            tri_color.append(np.tile(c if c is not None else [np.nan] * 3, (len(f), 1)))
            if skinned:
                sets = [(a.JOINTS_0, a.WEIGHTS_0), (getattr(a, "JOINTS_1", None), getattr(a, "WEIGHTS_1", None))]
                js, ws = [], []
                for ja, wa in sets:
                    if ja is None or wa is None:
                        continue
                    js.append(doc.accessor(ja).astype(np.int64))
                    ws.append(doc.accessor(wa).astype(np.float64))
                if not js:
                    raise InputError(doc.path, f"mesh {gm.name!r} has a skin but a primitive without "
                                               "JOINTS_0/WEIGHTS_0")
                joints.append(np.concatenate(js, axis=1))
                weights.append(np.concatenate(ws, axis=1))
        self.ok = bool(pts)
        if not self.ok:
            return
        self.base = np.concatenate(pts)
        nt = max(len(t) for t in targets)
        self.targets = np.concatenate([np.pad(t, ((0, nt - len(t)), (0, 0), (0, 0))) for t in targets], axis=1)
        self.default_weights = np.zeros(nt)
        dw = getattr(node, "weights", None) or gm.weights or []
        self.default_weights[:min(nt, len(dw))] = dw[:nt]
        self.points = self.morphed(self.default_weights)
        self.faces = np.concatenate(faces)
        self.tri_color = np.concatenate(tri_color)
        # faces without a material: no colour of their own (NaN); glTF's default material is white
        if np.isnan(self.tri_color).all():
            self.tri_color = None
            self.colors_differ = False
        else:
            self.tri_color = np.where(np.isnan(self.tri_color), 1.0, self.tri_color)
            self.colors_differ = bool(np.ptp(self.tri_color, axis=0).max() > 1e-6)
        self.uv = [None if any(u is None for u in uvs) else np.concatenate(uvs) for uvs in (uv0, uv1)]
        self.skin = node.skin
        if skinned:
            k = max(j.shape[1] for j in joints)
            self.joints = np.concatenate([np.pad(j, ((0, 0), (0, k - j.shape[1]))) for j in joints])
            self.weights = np.concatenate([np.pad(w, ((0, 0), (0, k - w.shape[1]))) for w in weights])
        if not np.isfinite(self.points).all() or not np.isfinite(self.targets).all():
            raise GeometryError(doc.path, f"mesh {self.name} has NaN/inf points")


    def morphed(self, weights) -> np.ndarray:
        """(N, 3) mesh-space points with morph ``weights`` (targets,) applied."""
        w = np.zeros(len(self.targets))
        w[:min(len(w), len(weights))] = np.asarray(weights, dtype=float)[:len(w)]
        if not w.any():
            return self.base
        return self.base + np.einsum("t,tnc->nc", w, self.targets)


def _to_model_mesh(doc, raw: _RawMesh, points: np.ndarray, flip: bool) -> Mesh:
    faces = raw.faces[:, ::-1].copy() if flip else raw.faces.copy()
    primvars = []
    for name, uv in zip(("st", "st1"), raw.uv):
        if uv is not None:
            st = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float32)
            primvars.append(Primvar(name, "texCoord2f[]", "vertex", st))
    area = 0.5 * np.linalg.norm(np.cross(points[faces[:, 1]] - points[faces[:, 0]],
                                         points[faces[:, 2]] - points[faces[:, 0]]), axis=1)
    color = None if raw.tri_color is None else \
        (raw.tri_color * area[:, None]).sum(0) / max(area.sum(), 1e-300)
    if raw.colors_differ:
        primvars.append(Primvar("displayColor", "color3f[]", "uniform", raw.tri_color.astype(np.float32)))
    n = len(faces)
    return Mesh(name=raw.name, points=points, faces=faces, face_vertex_counts=np.full(n, 3, dtype=np.int64),
                face_vertex_indices=faces.ravel().copy(), tri_to_poly=np.arange(n, dtype=np.int64),
                path=f"/{raw.name}", primvars=primvars, display_color=color)


# --------------------------------------------------------------------------
# skeleton and pose

def _joint_order(doc, joint_nodes) -> list[int]:
    """The skin's joint nodes ordered parents first: the skin's own order when
    it already is, else depth-first."""
    jset = set(joint_nodes)

    def joint_parent(j):
        p = doc.parent[j]
        while p >= 0 and p not in jset:
            p = doc.parent[p]
        return p
    pos = {j: i for i, j in enumerate(joint_nodes)}
    if all(joint_parent(j) < 0 or pos[joint_parent(j)] < pos[j] for j in joint_nodes):
        return list(joint_nodes)
    depth = {}
    for j in joint_nodes:
        d, p = 0, doc.parent[j]
        while p >= 0:
            d += p in jset
            p = doc.parent[p]
        depth[j] = d
    order, seen = [], set()

    def visit(j):
        if j in seen:
            return
        p = doc.parent[j]
        while p >= 0 and p not in jset:
            p = doc.parent[p]
        if p >= 0:
            visit(p)
        seen.add(j)
        order.append(j)
    for j in sorted(joint_nodes, key=lambda j: (depth[j], j)):
        visit(j)
    return order


def _limb_angles(names, parents, positions) -> tuple[float, float, float] | None:
    """(mean upper-arm, mean thigh angle from straight down, mean elbow +
    knee bend) in degrees, or None when the limbs are not found."""
    try:
        r = find_roles(names, parents, positions)
    except Exception:
        return None

    def unit(a, b):
        d = positions[r.roles[b]] - positions[r.roles[a]]
        return d / max(np.linalg.norm(d), 1e-12)
    out, bend = [], []
    for chains in ((("upper_arm_l", "forearm_l", "hand_l"), ("upper_arm_r", "forearm_r", "hand_r")),
                   (("thigh_l", "shin_l", "foot_l"), ("thigh_r", "shin_r", "foot_r"))):
        ang = []
        for a, b, c in chains:
            if a in r.roles and b in r.roles:
                u = unit(a, b)
                ang.append(np.degrees(np.arccos(np.clip(-u[1], -1, 1))))
                if c in r.roles:
                    bend.append(np.degrees(np.arccos(np.clip(u @ unit(b, c), -1, 1))))
        if not ang:
            return None
        out.append(float(np.mean(ang)))
    return out[0], out[1], float(np.mean(bend)) if bend else 0.0


def _raw_meshes(doc: GltfDocument) -> list[_RawMesh]:
    """Every mesh node with triangles, names made unique."""
    raws = [r for r in (_RawMesh(doc, i) for i, n in enumerate(doc.g.nodes) if n.mesh is not None) if r.ok]
    if not raws:
        raise GeometryError(doc.path, "the glTF holds no triangle meshes")
    names = [r.name for r in raws]
    for i, r in enumerate(raws):
        if names.count(r.name) > 1:
            r.name = f"{r.name}_{i}"
    return raws


def pose_meshes(doc: GltfDocument, raws: list[_RawMesh], node_world: np.ndarray,
                weights: dict | None = None) -> list[np.ndarray]:
    """(N, 3) scene-space points of each mesh for node matrices ``node_world``
    (nodes, 4, 4) and morph ``weights`` {node: (targets,)}: skinned meshes by
    glTF's LBS (their node's transform ignored), others by their node."""
    out = []
    for raw in raws:
        p = raw.morphed(weights[raw.node]) if weights and raw.node in weights else raw.points
        if raw.skin is None:
            w = node_world[raw.node]
            out.append(p @ w[:3, :3] + w[3, :3])
            continue
        skin_nodes = list(doc.g.skins[raw.skin].joints or [])
        ibm = _ibms(doc, raw.skin)
        skm = np.array([ibm[n] @ node_world[n] for n in skin_nodes])
        wts = np.maximum(raw.weights, 0.0)
        wts = wts / np.maximum(wts.sum(axis=1, keepdims=True), 1e-12)
        hom = np.c_[p, np.ones(len(p))]
        out.append(np.einsum("nk,nkc->nc", wts, np.einsum("nr,nkrc->nkc", hom, skm[raw.joints]))[:, :3])
    return out


def read_gltf_frames(path, frames=None):
    """Evaluate a glTF file for previews.

    Returns (character, meshes, fps, n_total): ``character`` as
    :func:`read_gltf_character` reads it (faces, colours, roles), ``meshes``
    one list of (N, 3) float32 scene-space frames per mesh in the order
    body, items, ``fps`` the frame rate (the file's ``asset.extras.fps`` when
    wearfit wrote it, else 24), ``n_total`` the frames of the whole first
    animation (1 without one: the character's pose). ``frames``: None (all)
    or a sequence of frame indices.
    """
    char = read_gltf_character(path, require_skeleton=False)
    doc = GltfDocument(path)
    extras = doc.g.asset.extras or {}
    fps = float(extras.get("fps", 24.0)) if isinstance(extras, dict) else 24.0
    order = [char.body] + list(char.items)
    if not doc.g.animations:
        return char, [[m.points.astype(np.float32)] for m in order], fps, 1
    raws = {f"/{r.name}": r for r in _raw_meshes(doc)}
    raw_list = [raws[m.path] for m in order]
    anim = AnimationSampler(doc, 0)
    n_total = int(np.floor((anim.end - anim.start) * fps + 1e-6)) + 1
    idx = range(n_total) if frames is None else frames
    out = [[] for _ in order]
    for f in idx:
        local, weights = anim.at(anim.start + f / fps)
        pts = pose_meshes(doc, raw_list, doc.world(local), weights)
        for k, p in enumerate(pts):
            out[k].append(p.astype(np.float32))
    return char, out, fps, n_total


def read_gltf_character(path, body_path: str | None = None, item_paths: list[str] | None = None,
                        require_skeleton: bool = True, pose: str | None = None) -> Character:
    """Read a glTF 2.0 character (``.glb`` or ``.gltf``) in internal space.

    Parameters
    ----------
    path : the file.
    body_path, item_paths : ``"/NAME"`` of the body mesh / the items (mesh
        node names made valid identifiers); default: the skinned mesh with
        most points / every other mesh.
    require_skeleton : refuse a file without a skinned mesh.
    pose : ``"auto"``, ``"bind"``, ``"nodes"`` or an animation's name (its
        first frame); default: :func:`set_default_pose`'s (``auto``).

    Returns
    -------
    Character with up_axis ``"Y"``, meters_per_unit 1, identity
    ``to_internal``; body and items (N, 3) in the chosen pose, skeleton
    ``bind_world`` = ``rest`` = that pose.
    """
    doc = GltfDocument(path)
    g = doc.g
    pose = pose or _default_pose
    if not g.meshes or not g.nodes:
        raise InputError(path, "the glTF holds no meshes")
    raws = _raw_meshes(doc)
    skinned = [r for r in raws if r.skin is not None]
    if body_path is not None:
        body_raw = next((r for r in raws if f"/{r.name}" == body_path), None)
        if body_raw is None:
            raise InputError(path, f"no mesh named {body_path}; meshes: {[f'/{r.name}' for r in raws]}")
        if body_raw.skin is None and require_skeleton:
            raise InputError(path, f"{body_path} has no skin")
    elif skinned:
        body_raw = max(skinned, key=lambda r: len(r.points))
    elif require_skeleton:
        raise InputError(path, "no skinned mesh: no mesh node has a skin (glTF skins[])")
    else:
        body_raw = max(raws, key=lambda r: len(r.points))

    node_world = doc.world()
    skeleton = None
    if body_raw.skin is not None:
        skin = g.skins[body_raw.skin]
        skin_joints = list(skin.joints or [])
        if not skin_joints:
            raise InputError(path, f"skin {body_raw.skin} has no joints")
        order = _joint_order(doc, skin_joints)
        idx_of = {n: i for i, n in enumerate(order)}
        jset = set(order)
        parents = np.full(len(order), -1, dtype=np.int64)
        for i, n in enumerate(order):
            p = doc.parent[n]
            while p >= 0 and p not in jset:
                p = doc.parent[p]
            parents[i] = idx_of[p] if p >= 0 else -1
        jnames = [joint_token(g.nodes[n].name or f"joint_{n}") for n in order]
        seen: dict[str, int] = {}
        for i, nm in enumerate(jnames):
            if nm in seen:
                jnames[i] = f"{nm}_{i}"
            seen[jnames[i]] = i
        paths = []
        for i in range(len(order)):
            paths.append(jnames[i] if parents[i] < 0 else f"{paths[parents[i]]}/{jnames[i]}")
        mesh_world = node_world[body_raw.node]
        ibm_by_node = _ibms(doc, body_raw.skin)
        bind_world = np.array([invert(ibm_by_node[n]) for n in order]) @ mesh_world
        candidates = {"bind": bind_world, "nodes": node_world[order]}
        node_poses = {"bind": None, "nodes": node_world}
        if pose == "auto":  # the animations' first frames are candidates too
            for a in g.animations or []:
                if a.name and a.name not in candidates:
                    node_poses[a.name] = doc.world(doc.animation_first_frame(a.name))
                    candidates[a.name] = node_poses[a.name][order]
            chosen, why = _auto_pose(jnames, parents, candidates)
            info(f"{path}: glTF pose {chosen!r} ({why}); --gltf-pose bind|nodes|ANIMATION picks another")
        elif pose in ("bind", "nodes"):
            chosen = pose
        else:
            chosen = pose
            node_poses[pose] = doc.world(doc.animation_first_frame(pose))
            candidates[pose] = node_poses[pose][order]
            info(f"{path}: glTF pose: first frame of animation {pose!r}")
        world_j = candidates[chosen]
        pose_nodes = node_poses[chosen]
        inv = invert(world_j)
        rest_local = np.array([world_j[j] if parents[j] < 0 else world_j[j] @ inv[parents[j]]
                               for j in range(len(order))])
        skeleton = Skeleton(joint_names=jnames, joint_paths=paths, parents=parents, bind_world=world_j,
                            rest_local=rest_local, skel_to_world=np.eye(4), path="/Skeleton")
    else:
        order, idx_of, pose_nodes = [], {}, node_world

    def place(raw: _RawMesh):
        """(points in the chosen pose (N, 3), joint indices, weights, flip)."""
        if raw.skin is None or skeleton is None:
            w = node_world[raw.node] if pose_nodes is None else pose_nodes[raw.node]
            return raw.points @ w[:3, :3] + w[3, :3], None, None, np.linalg.det(w[:3, :3]) < 0
        skin_nodes = list(g.skins[raw.skin].joints or [])
        if raw.joints.size and (raw.joints.min() < 0 or raw.joints.max() >= len(skin_nodes)):
            bad = int(raw.joints.max())
            raise InputError(path, f"mesh {raw.name}: skin weights reference joint {bad}, but its skin "
                                   f"has {len(skin_nodes)} joints")
        w = np.where(raw.weights > 0, raw.weights, 0.0)
        s = w.sum(axis=1, keepdims=True)
        if (s[:, 0] <= 1e-12).any():
            raise InputError(path, f"mesh {raw.name}: {int((s[:, 0] <= 1e-12).sum())} vertices have "
                                   "all-zero skin weights")
        w = w / s
        if pose_nodes is None:  # bind pose: the mesh as its node places it
            mw = node_world[body_raw.node]
            pts = raw.points @ mw[:3, :3] + mw[3, :3]
        else:  # LBS with the skin's own IBMs and the pose's node matrices
            pts = pose_meshes(doc, [raw], pose_nodes)[0]
        inside = all(n in idx_of for n in skin_nodes)
        if not inside:
            return pts, None, None, False
        remap = np.array([idx_of[n] for n in skin_nodes], dtype=np.int64)
        return pts, remap[raw.joints], w, False

    meshes = []
    for raw in raws:
        pts, ji, jw, flip = place(raw)
        m = _to_model_mesh(doc, raw, pts, flip)
        m.joint_indices, m.joint_weights = ji, jw
        meshes.append(m)
    body = meshes[raws.index(body_raw)]
    if item_paths is not None:
        by_path = {m.path: m for m in meshes}
        missing = [p for p in item_paths if p not in by_path]
        if missing:
            raise InputError(path, f"no mesh at item path {missing[0]}; meshes: {sorted(by_path)}")
        items = [by_path[p] for p in item_paths]
    else:
        items = [m for m in meshes if m is not body]
    return Character(source=str(path), up_axis="Y", meters_per_unit=1.0, to_internal=np.eye(4),
                     skeleton=skeleton, body=body, items=items, time_codes_per_second=24.0,
                     skel_root_path="")


def _ibms(doc: GltfDocument, skin_index: int) -> dict[int, np.ndarray]:
    """{joint node: (4, 4) row-vector inverse bind matrix} of a skin
    (identity where the skin gives none)."""
    skin = doc.g.skins[skin_index]
    joints = list(skin.joints or [])
    if skin.inverseBindMatrices is None:
        m = np.tile(np.eye(4), (len(joints), 1, 1))
    else:
        m = doc.accessor(skin.inverseBindMatrices).astype(np.float64).reshape(-1, 4, 4)
        if len(m) < len(joints):
            raise InputError(doc.path, f"skin {skin_index}: {len(m)} inverse bind matrices for "
                                       f"{len(joints)} joints")
    dets = np.linalg.det(m[:, :3, :3])
    if not np.isfinite(m).all() or (np.abs(dets) < 1e-12).any():
        raise InputError(doc.path, f"skin {skin_index}: singular or NaN inverse bind matrix")
    return {n: m[i] for i, n in enumerate(joints)}


def _auto_pose(names, parents, candidates: dict) -> tuple[str, str]:
    """The candidate pose closest to the dev references' rest pose (upper
    arms, thighs, straight elbows and knees), and a phrase saying why."""
    scores, texts = {}, {}
    for k, world in candidates.items():
        ang = _limb_angles(names, parents, world[:, 3, :3])
        if ang is None:
            continue
        scores[k] = abs(ang[0] - REFERENCE_ARM_DEG) + abs(ang[1] - REFERENCE_LEG_DEG) + ang[2]
        texts[k] = f"{k}: arms {ang[0]:.0f}, legs {ang[1]:.0f}, bend {ang[2]:.0f} deg"
    if not scores:
        return "bind", "limbs not found; the inverse bind matrices' pose"
    if np.allclose(candidates["bind"][:, 3, :3], candidates["nodes"][:, 3, :3], atol=1e-4):
        return "bind", "bind and nodes poses agree"
    best = min(scores, key=scores.get)
    shown = [texts[k] for k in dict.fromkeys([best, "bind", "nodes"]) if k in texts]
    more = f"; {len(texts) - len(shown)} animations' first frames scored too" if len(texts) > len(shown) else ""
    return best, (f"closest to the references' arms {REFERENCE_ARM_DEG:.0f} / legs "
                  f"{REFERENCE_LEG_DEG:.0f} deg, straight limbs; " + "; ".join(shown) + more)
