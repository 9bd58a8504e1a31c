"""glTF edge: write a wearfit scene (a ``dress``/``animate``/``fit`` output) as glTF 2.0 binary.

:func:`export_scene` reads the scene's body, skeleton and items through
:func:`wearfit_usd.io.usd.read_character` (internal space = glTF's: metres,
Y up, +Z forward), the materials through UsdShade, the skeleton's animation
through UsdSkel and point caches through ``UsdGeom.Mesh`` points (value
clips resolved by USD), and writes one ``.glb``:

* the skeleton as a node hierarchy (rest pose as the nodes' TRS, inverse
  bind matrices from the bind pose) and one skin;
* the body and every item bound to the skeleton through UsdSkel (any
  ``skel:skeleton`` binding: skinned items written by ``dress``/``animate``)
  as skinned meshes (``JOINTS_n``/``WEIGHTS_n``, 4 influences a set);
* items that are only time-sampled point meshes as static meshes at the
  first frame with one morph target per exported frame (``--morph-every``
  thins them) animated by a ``weights`` channel: one-hot keys that glTF
  viewers blend linearly between frames, so the shape is exact at every key.
  Node animation cannot deform a mesh, and re-deriving skin weights for a
  cloth cache would lose its dynamics: morph targets keep it exactly. An
  item present both as a skinned mesh and as a point cache (``--items both``)
  is written once, skinned (same prim name and topology, or same points);
* one material per mesh, and one per ``materialBind`` GeomSubset with its own
  binding (one primitive each over the same vertices): ``baseColorFactor`` from the bound
  ``UsdPreviewSurface``'s ``diffuseColor`` (its ``opacity``, ``metallic``
  and ``roughness`` too), ``baseColorTexture`` when ``diffuseColor`` is
  read from a ``UsdUVTexture`` file (embedded), else the mesh's
  ``displayColor``;
* the SkelAnimation sampled at every time code as translation/rotation/scale
  channels (channels that never move are left out).

UVs (``st``) that are face-varying split vertices on their seams, as glTF
needs one attribute value per vertex. Everything goes through
:func:`wearfit_usd.io.atomic.atomic_output`.
"""
from __future__ import annotations

import mimetypes
from pathlib import Path

import numpy as np

from ..errors import InputError, USDInputError
from ..geometry.closest import vertex_normals
from ..model import SKINNED_SUFFIX, Character, Mesh
from ..progress import progress, warn
from ..transforms import decompose, invert, quat_from_matrix, transform_points
from .atomic import atomic_output
from .usd import open_stage, read_character, triangulate

FLOAT, UINT16, UINT32 = 5126, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


class _Blob:
    """The GLB binary chunk, with one bufferView per accessor (4-byte aligned)."""

    def __init__(self, gltf):
        self.g = gltf
        self.data = bytearray()

    def add(self, array: np.ndarray, gl_type: str, component: int, target=None, minmax: bool = False) -> int:
        import pygltflib
        arr = np.ascontiguousarray(array)
        pad = (-len(self.data)) % 4
        self.data += b"\0" * pad
        offset = len(self.data)
        self.data += arr.tobytes()
        self.g.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=offset, byteLength=arr.nbytes,
                                                       target=target))
        acc = pygltflib.Accessor(bufferView=len(self.g.bufferViews) - 1, componentType=component,
                                 count=int(arr.shape[0]), type=gl_type)
        if minmax:
            flat = arr.reshape(arr.shape[0], -1)
            acc.min = [float(v) for v in flat.min(axis=0)]
            acc.max = [float(v) for v in flat.max(axis=0)]
        self.g.accessors.append(acc)
        return len(self.g.accessors) - 1

    def add_image(self, data: bytes, mime: str) -> int:
        import pygltflib
        pad = (-len(self.data)) % 4
        self.data += b"\0" * pad
        offset = len(self.data)
        self.data += data
        self.g.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=offset, byteLength=len(data)))
        self.g.images.append(pygltflib.Image(bufferView=len(self.g.bufferViews) - 1, mimeType=mime))
        return len(self.g.images) - 1


# --------------------------------------------------------------------------
# reading the scene (USD)

def _material(prim, fallback_color, scene_path):
    """{color (4,), metallic, roughness, texture (path or None), name} of the
    UsdPreviewSurface bound to ``prim`` (else its displayColor; None without either)."""
    from pxr import UsdShade
    out = {"color": np.r_[fallback_color if fallback_color is not None else [0.8, 0.8, 0.8], 1.0],
           "metallic": 0.0, "roughness": 0.8, "texture": None, "name": None}
    mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if not mat:
        return out if fallback_color is not None else None
    out["name"] = mat.GetPrim().GetName()
    surf = mat.ComputeSurfaceSource()[0]
    if not surf or surf.GetIdAttr().Get() != "UsdPreviewSurface":
        return out

    def value(name):
        inp = surf.GetInput(name)
        if not inp:
            return None, None
        src = inp.GetConnectedSources()[0] if inp.HasConnectedSource() else []
        if src:
            shader = UsdShade.Shader(src[0].source.GetPrim())
            if shader.GetIdAttr().Get() == "UsdUVTexture":
                f = shader.GetInput("file")
                asset = f.Get() if f else None
                if asset is not None:
                    return None, (asset.resolvedPath or asset.path)
            return None, None
        return inp.Get(), None
    c, tex = value("diffuseColor")
    if c is not None:
        out["color"][:3] = np.asarray(c, dtype=float)
    out["texture"] = tex
    for key, name in (("metallic", "metallic"), ("roughness", "roughness")):
        v, _ = value(name)
        if v is not None:
            out[key] = float(v)
    op, _ = value("opacity")
    if op is not None:
        out["color"][3] = float(op)
    return out


def _uv_corners(mesh: Mesh) -> np.ndarray | None:
    """(corners, 2) UVs per face corner (``face_vertex_indices`` order) from
    the ``st`` primvar (vertex or faceVarying), or None."""
    pv = next((p for p in mesh.primvars if p.name == "st" or p.type_name.startswith("texCoord2")), None)
    if pv is None:
        return None
    vals = np.asarray(pv.values, dtype=np.float64).reshape(-1, 2)
    if pv.indices is not None:
        vals = vals[pv.indices]
    if pv.interpolation in ("vertex", "varying") and len(vals) == mesh.n_points:
        return vals[mesh.face_vertex_indices]
    if pv.interpolation == "faceVarying" and len(vals) == len(mesh.face_vertex_indices):
        return vals
    return None


def _layout(mesh: Mesh):
    """glTF vertices of a mesh: (source point per vertex (V,), UV per vertex
    (V, 2) or None, triangles (T, 3) into the vertices, polygon of each
    triangle (T,))."""
    fvi = np.asarray(mesh.face_vertex_indices, dtype=np.int64)
    uv = _uv_corners(mesh)
    corners_tri, poly = triangulate(mesh.face_vertex_counts, np.arange(len(fvi)), mesh.left_handed)
    if uv is None:
        return np.arange(mesh.n_points), None, fvi[corners_tri], poly
    key = np.column_stack([fvi.astype(np.float64), uv])
    uniq, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    return fvi[first], uv[first], inverse[corners_tri], poly


def _material_groups(prim, mesh: Mesh, poly: np.ndarray, scene_path) -> list:
    """[(triangle mask (T,), material dict or None)]: one group per
    ``materialBind`` GeomSubset of ``prim`` with a material of its own (its
    polygons), and the rest with the mesh's material (:func:`_material`);
    empty groups left out. ``poly``: the polygon of each triangle."""
    from pxr import UsdGeom, UsdShade
    whole = _material(prim, mesh.display_color, scene_path) if prim is not None else None
    if prim is None:
        return [(np.ones(len(poly), dtype=bool), whole)]
    groups, rest = [], np.ones(len(poly), dtype=bool)
    for sub in UsdGeom.Subset.GetGeomSubsets(UsdGeom.Imageable(prim), UsdGeom.Tokens.face, "materialBind"):
        mat, _ = UsdShade.MaterialBindingAPI(sub.GetPrim()).ComputeBoundMaterial()
        if not mat:
            continue
        ids = np.asarray(sub.GetIndicesAttr().Get() or [], dtype=np.int64)
        mask = np.isin(poly, ids) & rest
        if mask.any():
            groups.append((mask, _material(sub.GetPrim(), mesh.display_color, scene_path)))
            rest &= ~mask
    if rest.any():
        groups.append((rest, whole))
    return groups


def _plain_name(path: str) -> str:
    """The prim name of ``path`` without the skinned copies' suffix."""
    name = path.rsplit("/", 1)[-1]
    return name[:-len(SKINNED_SUFFIX)] if name.endswith(SKINNED_SUFFIX) else name


def _is_wearfit_scene(stage) -> bool:
    return bool(stage.GetPrimAtPath("/Root/Character/Body"))


def export_scene(scene, out, morph_every: int = 1, max_frames: int | None = None) -> dict:
    """Write the wearfit scene ``scene`` (USD) to ``out`` (``.glb``).

    Parameters
    ----------
    scene : a ``dress``, ``animate`` or ``fit`` output.
    out : the ``.glb`` to write (atomically).
    morph_every : point-cache items get a morph target every N frames.
    max_frames : export only the first N frames.

    Returns
    -------
    dict of figures: size_bytes, meshes, skinned, morphed, morph_targets,
    joints, frames, materials, textures.
    """
    import pygltflib
    from pxr import UsdGeom

    scene = Path(scene)
    stage = open_stage(scene)
    if not _is_wearfit_scene(stage):
        raise USDInputError(scene, "not a wearfit scene (no /Root/Character/Body): export takes the output "
                                   "of wearfit dress, animate or fit")
    char: Character = read_character(scene, require_skeleton=False, skinned_copies=True)
    to_int = char.to_internal
    skel = char.skeleton
    start, end = float(stage.GetStartTimeCode()), float(stage.GetEndTimeCode())
    if not stage.HasAuthoredTimeCodeRange():
        start = end = 0.0
    times = np.arange(start, end + 0.5)
    if max_frames is not None:
        times = times[:max_frames]
    tcps = float(stage.GetTimeCodesPerSecond()) or 24.0
    seconds = ((times - times[0]) / tcps).astype(np.float32)

    g = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0", generator="wearfit_usd export",
                                              extras={"fps": tcps, "source": scene.name}),
                        scenes=[pygltflib.Scene(nodes=[])], scene=0, nodes=[], meshes=[], materials=[],
                        accessors=[], bufferViews=[], buffers=[], skins=[], animations=[], images=[],
                        textures=[], samplers=[])
    blob = _Blob(g)
    roots = g.scenes[0].nodes
    channels, samplers = [], []

    def channel(node, path, values, gl_type):
        samplers.append(pygltflib.AnimationSampler(input=time_acc, output=blob.add(values, gl_type, FLOAT),
                                                   interpolation="LINEAR"))
        channels.append(pygltflib.AnimationChannel(sampler=len(samplers) - 1,
                                                   target=pygltflib.AnimationChannelTarget(node=node, path=path)))
    time_acc = blob.add(seconds[:, None], "SCALAR", FLOAT, minmax=True) if len(times) > 1 else None

    # ---- skeleton: nodes (rest pose), skin (bind pose), animation
    skin_index = None
    joint_nodes: list[int] = []
    if skel is not None:
        rest_world = skel.rest_world()
        rest_local_int = np.array([rest_world[j] if p < 0 else rest_world[j] @ invert(rest_world[p])
                                   for j, p in enumerate(skel.parents)])
        t, r, s = decompose(rest_local_int)
        q = quat_from_matrix(r)[:, [1, 2, 3, 0]]
        for j, name in enumerate(skel.joint_names):
            node = pygltflib.Node(name=name, translation=[float(v) for v in t[j]],
                                  rotation=[float(v) for v in q[j]], children=[])
            if not np.allclose(s[j], 1.0, atol=1e-6):
                node.scale = [float(v) for v in s[j]]
            g.nodes.append(node)
            joint_nodes.append(len(g.nodes) - 1)
        for j, p in enumerate(skel.parents):
            if p >= 0:
                g.nodes[joint_nodes[p]].children.append(joint_nodes[j])
            else:
                roots.append(joint_nodes[j])
        ibm = invert(skel.bind_world).astype(np.float32).reshape(-1, 16)
        ibm[:, [3, 7, 11]] = 0.0
        ibm[:, 15] = 1.0
        g.skins.append(pygltflib.Skin(name="Skeleton", joints=joint_nodes, inverseBindMatrices=blob.add(
            ibm, "MAT4", FLOAT), skeleton=joint_nodes[int(np.flatnonzero(skel.parents < 0)[0])]))
        skin_index = 0
        if len(times) > 1:
            _animate_skeleton(g, stage, skel, times, joint_nodes, channel)

    # ---- meshes
    cache_prims = {}
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            cache_prims[str(prim.GetPath())] = prim
    items = list(char.items)
    skinned_items = [m for m in items if m.joint_indices is not None and skel is not None]
    drop = set()
    for m in items:
        if m.joint_indices is not None:
            continue
        for s_ in skinned_items:  # the same item also written skinned (--items both): keep that one
            same_name = _plain_name(s_.path) == _plain_name(m.path)
            if (s_.n_points == m.n_points and np.array_equal(s_.faces, m.faces)
                    and (same_name or np.abs(s_.points - m.points).max() < 1e-3)):
                drop.add(m.path)
    figures = {"meshes": 0, "skinned": 0, "morphed": 0, "morph_targets": 0, "textures": 0}
    morph_times = times[::morph_every]
    key_acc = None
    for mesh in [char.body] + [m for m in items if m.path not in drop]:
        prim = cache_prims.get(mesh.path)
        src, uv, tris, poly = _layout(mesh)
        skinned = mesh.joint_indices is not None and skin_index is not None
        frames = None
        if not skinned and prim is not None and len(morph_times) > 1 and mesh is not char.body:
            frames = _point_frames(prim, morph_times, to_int, mesh, scene)
        base = mesh.points if frames is None else frames[0]
        pts0 = base[src]
        attrs = pygltflib.Attributes()
        attrs.POSITION = blob.add(pts0.astype(np.float32), "VEC3", FLOAT, ARRAY_BUFFER, minmax=True)
        nrm = vertex_normals(base, mesh.faces)[src]
        bad = ~np.isfinite(nrm).all(axis=1) | (np.linalg.norm(nrm, axis=1) < 1e-6)
        nrm[bad] = (0.0, 1.0, 0.0)
        nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)
        attrs.NORMAL = blob.add(nrm, "VEC3", FLOAT, ARRAY_BUFFER)
        if uv is not None:
            st = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float32)
            attrs.TEXCOORD_0 = blob.add(st, "VEC2", FLOAT, ARRAY_BUFFER)
        if skinned:
            _skin_attributes(blob, attrs, mesh.joint_indices[src], mesh.joint_weights[src])
        idx_type = UINT16 if len(src) < 65535 else UINT32
        # one primitive per material: the mesh's, and each materialBind GeomSubset's own (same vertices)
        primitives = []
        for mask, material in _material_groups(prim, mesh, poly, scene):
            idx = blob.add(tris[mask].astype(np.uint16 if idx_type == UINT16 else np.uint32).ravel()[:, None],
                           "SCALAR", idx_type, ELEMENT_ARRAY_BUFFER)
            # no material and no displayColor: none written (viewers use their default, wearfit its item colours)
            mat_index = None if material is None else _add_material(g, blob, material, mesh.name, uv is not None,
                                                                     figures)
            primitives.append(pygltflib.Primitive(attributes=attrs, indices=idx, material=mat_index, mode=4))
        # the prim's name (read_character numbers duplicates); a skinned copy
        # exported instead of its point cache takes the item's own name
        name = mesh.path.rsplit("/", 1)[-1] or mesh.name
        if mesh.joint_indices is not None and any(_plain_name(d) == _plain_name(mesh.path) for d in drop):
            name = _plain_name(mesh.path)
        gmesh = pygltflib.Mesh(name=name, primitives=primitives)
        node = pygltflib.Node(name=name, mesh=len(g.meshes))
        g.meshes.append(gmesh)
        g.nodes.append(node)
        roots.append(len(g.nodes) - 1)
        figures["meshes"] += 1
        if skinned:
            node.skin = skin_index
            figures["skinned"] += 1
        elif frames is not None:
            deltas = frames[1:, src] - pts0[None]
            targets = [{"POSITION": blob.add(d.astype(np.float32), "VEC3", FLOAT, ARRAY_BUFFER,
                                             minmax=True)} for d in deltas]
            for primitive in primitives:  # the primitives share their vertices, so their morph targets
                primitive.targets = targets
            gmesh.weights = [0.0] * len(deltas)
            gmesh.extras = {"targetNames": [f"frame_{t:g}" for t in morph_times[1:]]}
            if key_acc is None:
                key_acc = blob.add(seconds[::morph_every][:, None], "SCALAR", FLOAT, minmax=True)
            onehot = np.zeros((len(morph_times), len(deltas)), dtype=np.float32)
            onehot[np.arange(1, len(morph_times)), np.arange(len(deltas))] = 1.0
            samplers.append(pygltflib.AnimationSampler(input=key_acc, output=blob.add(
                onehot.reshape(-1, 1), "SCALAR", FLOAT), interpolation="LINEAR"))
            channels.append(pygltflib.AnimationChannel(
                sampler=len(samplers) - 1,
                target=pygltflib.AnimationChannelTarget(node=len(g.nodes) - 1, path="weights")))
            figures["morphed"] += 1
            figures["morph_targets"] += len(deltas)
    if channels:
        g.animations.append(pygltflib.Animation(name="wearfit", channels=channels, samplers=samplers))
    for key in ("skins", "animations", "images", "textures", "samplers"):
        if not getattr(g, key):
            setattr(g, key, [])
    g.buffers.append(pygltflib.Buffer(byteLength=len(blob.data)))
    g.set_binary_blob(bytes(blob.data))
    out = Path(out)
    with atomic_output(out) as tmp:
        g.save_binary(tmp)
    figures.update(size_bytes=out.stat().st_size, joints=0 if skel is None else skel.n_joints,
                   frames=int(len(times)), materials=len(g.materials))
    return figures


def _skin_attributes(blob, attrs, ji: np.ndarray, jw: np.ndarray) -> None:
    """JOINTS_n / WEIGHTS_n (sets of 4; unused slots joint 0 weight 0; weights
    renormalised in float32)."""
    k = ji.shape[1]
    order = np.argsort(-jw, axis=1, kind="stable")
    ji = np.take_along_axis(ji, order, 1)
    jw = np.take_along_axis(jw, order, 1)
    sets = max(1, -(-k // 4))
    ji = np.pad(ji, ((0, 0), (0, sets * 4 - k)))
    jw = np.pad(jw, ((0, 0), (0, sets * 4 - k)))
    jw = np.where(jw < 1e-6, 0.0, jw)
    ji = np.where(jw > 0, ji, 0)
    jw = (jw / jw.sum(axis=1, keepdims=True)).astype(np.float32)
    jw[:, 0] += np.float32(1.0) - jw.sum(axis=1, dtype=np.float32)
    ji_type = np.uint16
    for i in range(sets):
        setattr(attrs, f"JOINTS_{i}", blob.add(ji[:, 4 * i:4 * i + 4].astype(ji_type), "VEC4", UINT16, ARRAY_BUFFER))
        setattr(attrs, f"WEIGHTS_{i}", blob.add(jw[:, 4 * i:4 * i + 4], "VEC4", FLOAT, ARRAY_BUFFER))


def _add_material(g, blob, mat: dict, mesh_name: str, has_uv: bool, figures: dict) -> int:
    import pygltflib
    color = np.clip(np.asarray(mat["color"], dtype=float), 0.0, 1.0)
    pbr = pygltflib.PbrMetallicRoughness(baseColorFactor=[float(c) for c in color],
                                         metallicFactor=float(np.clip(mat["metallic"], 0, 1)),
                                         roughnessFactor=float(np.clip(mat["roughness"], 0, 1)))
    tex = mat.get("texture")
    if tex and has_uv:
        f = Path(tex)
        mime = mimetypes.guess_type(f.name)[0]
        if f.exists() and mime in ("image/png", "image/jpeg"):
            if not g.samplers:
                g.samplers.append(pygltflib.Sampler())
            img = blob.add_image(f.read_bytes(), mime)
            g.textures.append(pygltflib.Texture(source=img, sampler=0))
            pbr.baseColorTexture = pygltflib.TextureInfo(index=len(g.textures) - 1)
            pbr.baseColorFactor = [1.0, 1.0, 1.0, float(color[3])]
            figures["textures"] += 1
        else:
            warn(f"{mesh_name}: texture {tex} not embedded (missing, or not PNG/JPEG)")
    g.materials.append(pygltflib.Material(name=mat.get("name") or mesh_name, pbrMetallicRoughness=pbr,
                                          alphaMode="BLEND" if color[3] < 0.999 else "OPAQUE",
                                          doubleSided=True))
    return len(g.materials) - 1


def _animate_skeleton(g, stage, skel, times, joint_nodes, channel) -> None:
    """Translation/rotation/scale channels of every joint that moves, sampled
    at each time code from the Skeleton's animation (UsdSkel)."""
    from pxr import Usd, UsdSkel
    cache = UsdSkel.Cache()
    prim = stage.GetPrimAtPath(skel.path)
    sq = None
    for root in stage.Traverse():
        if root.IsA(UsdSkel.Root):
            cache.Populate(UsdSkel.Root(root), Usd.PrimDefaultPredicate)
    sq = cache.GetSkelQuery(UsdSkel.Skeleton(prim))
    if not sq or not sq.GetAnimQuery():
        return
    order = [str(j) for j in sq.GetJointOrder()]
    remap = np.array([order.index(p) for p in skel.joint_paths])
    world = np.empty((len(times), skel.n_joints, 4, 4))
    for f, t in enumerate(progress(times, total=len(times), desc="export: skeleton")):
        m = np.array(sq.ComputeJointSkelTransforms(Usd.TimeCode(float(t))), dtype=np.float64).reshape(-1, 4, 4)
        world[f] = m[remap] @ skel.skel_to_world
    inv = invert(world)
    local = world.copy()
    for j, p in enumerate(skel.parents):
        if p >= 0:
            local[:, j] = world[:, j] @ inv[:, p]
    t, r, s = decompose(local)
    q = quat_from_matrix(r)[..., [1, 2, 3, 0]]
    for j in range(1, len(q)):  # continuous quaternions for linear interpolation
        flip = (q[j] * q[j - 1]).sum(axis=-1) < 0
        q[j][flip] *= -1
    for j in range(skel.n_joints):  # channels whose every key equals the node's rest value are left out
        node = g.nodes[joint_nodes[j]]
        rest_q = np.asarray(node.rotation)
        if np.abs(t[:, j] - np.asarray(node.translation)).max() > 1e-7:
            channel(joint_nodes[j], "translation", t[:, j].astype(np.float32), "VEC3")
        if (1.0 - np.abs(q[:, j] @ rest_q)).max() > 1e-9:
            channel(joint_nodes[j], "rotation", q[:, j].astype(np.float32), "VEC4")
        if np.abs(s[:, j] - np.asarray(node.scale if node.scale is not None else [1.0, 1.0, 1.0])).max() > 1e-6:
            channel(joint_nodes[j], "scale", s[:, j].astype(np.float32), "VEC3")


def _point_frames(prim, times, to_int, mesh: Mesh, scene) -> np.ndarray | None:
    """(F, N, 3) internal points of a point-cache mesh at ``times``, or None
    when the points are not time-sampled."""
    from pxr import Usd, UsdGeom
    attr = UsdGeom.Mesh(prim).GetPointsAttr()
    if not attr.ValueMightBeTimeVarying():
        return None
    xf = UsdGeom.XformCache()
    out = np.empty((len(times), mesh.n_points, 3))
    for f, t in enumerate(progress(times, total=len(times), desc=f"export: {mesh.name}")):
        tc = Usd.TimeCode(float(t))
        v = attr.Get(tc)
        if v is None or len(v) != mesh.n_points:
            raise InputError(scene, f"{prim.GetPath()}: points missing or changing count at time {t:g}")
        xf.SetTime(tc)
        m = np.asarray(xf.GetLocalToWorldTransform(prim), dtype=np.float64) @ to_int
        out[f] = transform_points(np.asarray(v, dtype=np.float64), m)
    return out

