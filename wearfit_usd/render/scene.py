"""Read a USD stage into a numpy scene description, frame by frame.

:func:`read_scene` evaluates every visible Mesh of a stage at the selected
time codes and returns a :class:`SceneDescription`: per mesh its triangles,
a colour, and its points per frame in internal space (Y up, metres, whatever
the stage's upAxis and metersPerUnit). Skinned meshes are posed through
UsdSkel (``UsdSkel.Cache`` -> ``SkelQuery.ComputeSkinningTransforms`` ->
``SkinningQuery.ComputeSkinnedPoints``) at each time code; other meshes use
their (possibly time-sampled) points and transforms. Faces in a mesh's
``hidden_under_items`` GeomSubset (the body under the items) are not drawn.

A frame whose points equal the previous frame's reuses the same array object,
so the renderer can skip re-uploading unchanged meshes by identity.
No OpenGL here: description only.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError, USDInputError
from ..io.gltf import is_gltf, read_gltf_frames
from ..io.usd_carry import HIDDEN_SUBSET
from ..model import without_skinned_copies
from ..transforms import stage_to_internal, transform_points
from .lighting import BODY_COLOR, item_colors


@dataclass
class SceneMesh:
    """One mesh of the scene.

    faces: (T, 3) int64 triangles, counter-clockwise from outside.
    frames: one (N, 3) float32 internal-space array per scene frame (the same
        object repeated while the mesh does not move).
    color: (3,) sRGB 0-1 (the stage's displayColor when authored).
    role: ``"body"`` (the skinned mesh with most points, else the largest
        mesh) or ``"item"``.
    """
    name: str
    path: str
    role: str
    faces: np.ndarray
    frames: list[np.ndarray]
    color: np.ndarray
    color_authored: bool = False
    skinned: bool = False

    @property
    def n_points(self) -> int:
        return int(self.frames[0].shape[0])

    @property
    def animated(self) -> bool:
        return any(f is not self.frames[0] for f in self.frames[1:])


@dataclass
class SceneDescription:
    source: str
    up_axis: str
    meters_per_unit: float
    times: list[float]                 # time codes of the frames
    time_range: tuple[float, float]    # the stage's full range
    fps: float                         # time codes per second
    meshes: list[SceneMesh] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return len(self.times)

    @property
    def body(self) -> SceneMesh | None:
        return next((m for m in self.meshes if m.role == "body"), None)

    @property
    def items(self) -> list[SceneMesh]:
        return [m for m in self.meshes if m.role == "item"]

    def bounds(self, frames: list[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) (3,) box of every mesh over the given frames (default all)."""
        idx = range(self.n_frames) if frames is None else frames
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for m in self.meshes:
            seen = set()
            for i in idx:
                f = m.frames[i]
                if id(f) in seen:
                    continue
                seen.add(id(f))
                lo = np.minimum(lo, f.min(axis=0))
                hi = np.maximum(hi, f.max(axis=0))
        return lo, hi

    def frame_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(los, his) (F, 3): the box of every mesh at each frame."""
        los = np.full((self.n_frames, 3), np.inf)
        his = np.full((self.n_frames, 3), -np.inf)
        for m in self.meshes:
            cache = {}
            for i, f in enumerate(m.frames):
                if id(f) not in cache:
                    cache[id(f)] = (f.min(axis=0), f.max(axis=0))
                lo, hi = cache[id(f)]
                los[i] = np.minimum(los[i], lo)
                his[i] = np.maximum(his[i], hi)
        return los, his

    @property
    def n_triangles(self) -> int:
        return int(sum(len(m.faces) for m in self.meshes))


def parse_frames(spec: str | None) -> tuple[float | None, float | None] | None:
    """``"A:B"`` (inclusive time codes), ``"A:"``, ``":B"`` or ``"A"`` ->
    (start, end) with None for an open end; None/"" -> None (all frames).
    Raises ValueError on malformed text."""
    if spec is None or str(spec).strip() == "":
        return None
    s = str(spec).strip()
    if ":" in s:
        a, _, b = s.partition(":")
        start = float(a) if a.strip() else None
        end = float(b) if b.strip() else None
    else:
        start = end = float(s)
    if start is not None and end is not None and end < start:
        raise ValueError(f"bad frame range {spec!r}: end before start")
    return start, end


def _stage_time_range(stage, meshes, skel_queries) -> tuple[float, float]:
    """The stage's authored start/end, else the span of the time samples that
    move geometry, else (0, 0) for a static stage."""
    if stage.HasAuthoredTimeCodeRange():
        s, e = float(stage.GetStartTimeCode()), float(stage.GetEndTimeCode())
        return (s, max(s, e))
    from pxr import UsdGeom
    samples: list[float] = []
    for prim in meshes:
        samples += UsdGeom.Mesh(prim).GetPointsAttr().GetTimeSamples()
        p = prim
        while p and not p.IsPseudoRoot():
            xf = UsdGeom.Xformable(p)
            if xf:
                for op in xf.GetOrderedXformOps():
                    samples += op.GetAttr().GetTimeSamples()
            p = p.GetParent()
    for sq in skel_queries:
        aq = sq.GetAnimQuery()
        if aq:
            samples += list(aq.GetJointTransformTimeSamples())
    if not samples:
        return (0.0, 0.0)
    return (float(min(samples)), float(max(samples)))


def select_times(time_range: tuple[float, float], frames, path) -> list[float]:
    """Integer-step time codes of ``frames`` ((start, end) or None) inside
    ``time_range``; InputError when the request leaves the stage's range."""
    s0, e0 = time_range
    if frames is None:
        start, end = s0, e0
    else:
        start = s0 if frames[0] is None else float(frames[0])
        end = e0 if frames[1] is None else float(frames[1])
    eps = 1e-6
    if start < s0 - eps or end > e0 + eps or end < start:
        what = f"{start:g}" if start == end else f"{start:g}:{end:g}"
        raise InputError(path, f"frames {what} are outside the stage's time range "
                               f"{s0:g}:{e0:g}")
    n = int(np.floor(end - start + eps)) + 1
    return [start + i for i in range(n)]


def _triangles(prim, path, time):
    from pxr import UsdGeom

    from ..io.usd import triangulate
    mesh = UsdGeom.Mesh(prim)
    counts = mesh.GetFaceVertexCountsAttr().Get(time)
    idx = mesh.GetFaceVertexIndicesAttr().Get(time)
    if counts is None or idx is None or len(counts) == 0:
        return None
    counts = np.asarray(counts, dtype=np.int64)
    idx = np.asarray(idx, dtype=np.int64)
    if counts.sum() != len(idx):
        raise USDInputError(path, f"mesh {prim.GetPath()}: faceVertexCounts sum {counts.sum()} "
                                  f"!= {len(idx)} faceVertexIndices")
    left = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    faces, t2p = triangulate(counts, idx, left)
    # body faces the items cover (dress/animate's GeomSubset) are not drawn
    sub = prim.GetChild(HIDDEN_SUBSET)
    hidden = sub.GetAttribute("indices").Get(time) if sub and sub.IsA(UsdGeom.Subset) else None
    if hidden is not None and len(hidden):
        faces = faces[~np.isin(t2p, np.asarray(hidden, dtype=np.int64))]
    return faces


def _display_color(prim):
    from pxr import UsdGeom
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
    if not pv or not pv.HasAuthoredValue():
        return None
    val = pv.ComputeFlattened()
    if val is None or len(val) == 0:
        return None
    c = np.asarray(val, dtype=np.float64).reshape(-1, 3).mean(axis=0)
    return np.clip(c, 0.0, 1.0)


def read_scene(path, frames=None, progress_desc: str | None = None) -> SceneDescription:
    """Evaluate every visible Mesh of the stage at ``path`` at the selected
    frames. ``frames``: None (the stage's whole range), (start, end)
    inclusive time codes (None = open end) or an ``"A:B"`` string.

    Raises InputError (missing file, no meshes, frames outside the range)."""
    from pxr import Usd, UsdGeom, UsdSkel, Vt

    from ..io.usd import open_stage

    if isinstance(frames, str):
        try:
            frames = parse_frames(frames)
        except ValueError as exc:
            raise InputError(path, str(exc)) from None
    p = Path(path)
    if not p.exists():
        raise InputError(path, "file not found")
    if is_gltf(p):
        return _gltf_scene(p, frames)
    stage = open_stage(p)
    up = str(UsdGeom.GetStageUpAxis(stage))
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    to_int = stage_to_internal(up, mpu)

    meshes = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        img = UsdGeom.Imageable(prim)
        if img.ComputeVisibility() == UsdGeom.Tokens.invisible:
            continue
        if img.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
            continue
        meshes.append(prim)
    if not meshes:
        raise USDInputError(path, "the stage holds no visible Mesh prims: nothing to render")
    # `dress --items both` writes each item twice (points, and a skinned copy
    # <item>_skinned in the same place): draw one
    meshes = [prim for prim, keep in zip(meshes, without_skinned_copies([p.GetName() for p in meshes])) if keep]

    # skinned meshes through UsdSkel
    cache = UsdSkel.Cache()
    pred = Usd.PrimDefaultPredicate
    skinned = {}  # prim path -> (skinning query, skel query, skeleton prim)
    for root in stage.Traverse():
        if not root.IsA(UsdSkel.Root):
            continue
        sroot = UsdSkel.Root(root)
        cache.Populate(sroot, pred)
        for binding in cache.ComputeSkelBindings(sroot, pred):
            skel = binding.GetSkeleton()
            sq = cache.GetSkelQuery(skel)
            for target in binding.GetSkinningTargets():
                if target.GetPrim().IsA(UsdGeom.Mesh) and target.HasJointInfluences():
                    skinned[target.GetPrim().GetPath()] = (target, sq, skel.GetPrim())

    time_range = _stage_time_range(stage, meshes, [v[1] for v in skinned.values()])
    times = select_times(time_range, frames, path)

    t_first = Usd.TimeCode(times[0])

    def npts(prim):  # at the first frame: points may exist only as time samples
        v = UsdGeom.Mesh(prim).GetPointsAttr().Get(t_first)
        return 0 if v is None else len(v)

    # body: the skinned mesh with most points, else the largest mesh
    cands = [m for m in meshes if m.GetPath() in skinned] or meshes
    body_prim = max(cands, key=npts)

    entries = []
    for prim in meshes:
        faces = _triangles(prim, path, t_first)
        n = npts(prim)
        if faces is None or n == 0 or len(faces) == 0:
            continue  # empty mesh: nothing to draw
        if faces.min() < 0 or faces.max() >= n:
            raise USDInputError(path, f"mesh {prim.GetPath()}: face vertex index out of range")
        entries.append((prim, faces))
    if not entries:
        raise USDInputError(path, "every Mesh in the stage is empty: nothing to render")

    xf_cache = UsdGeom.XformCache()
    out_meshes = []
    names = [prim.GetName() for prim, _ in entries if prim != body_prim]
    colors = iter(item_colors(names))
    for prim, faces in entries:
        mesh = UsdGeom.Mesh(prim)
        pts_attr = mesh.GetPointsAttr()
        sk = skinned.get(prim.GetPath())
        frames_out: list[np.ndarray] = []
        prev = None
        n0 = npts(prim)
        for t in times:
            tc = Usd.TimeCode(t)
            xf_cache.SetTime(tc)
            pts = pts_attr.Get(tc)
            if pts is None or len(pts) != n0:
                raise USDInputError(path, f"mesh {prim.GetPath()}: points missing or changing "
                                          f"count at time {t:g}")
            if sk is not None:
                skq, sq, skel_prim = sk
                xforms = sq.ComputeSkinningTransforms(tc)
                pts = Vt.Vec3fArray(pts)
                if not skq.ComputeSkinnedPoints(xforms, pts, tc):
                    raise USDInputError(path, f"mesh {prim.GetPath()}: UsdSkel could not skin it "
                                              f"at time {t:g}")
                m = np.asarray(xf_cache.GetLocalToWorldTransform(skel_prim), dtype=np.float64)
            else:
                m = np.asarray(xf_cache.GetLocalToWorldTransform(prim), dtype=np.float64)
            world = transform_points(np.asarray(pts, dtype=np.float64), m @ to_int).astype(np.float32)
            if not np.isfinite(world).all():
                raise USDInputError(path, f"mesh {prim.GetPath()}: NaN/inf points at time {t:g}")
            if prev is not None and np.array_equal(prev, world):
                world = prev
            frames_out.append(world)
            prev = world
        authored = _display_color(prim)
        role = "body" if prim == body_prim else "item"
        default = np.asarray(BODY_COLOR if role == "body" else next(colors), dtype=np.float64)
        out_meshes.append(SceneMesh(
            name=prim.GetName(), path=str(prim.GetPath()), role=role, faces=faces,
            frames=frames_out, color=authored if authored is not None else default,
            color_authored=authored is not None, skinned=sk is not None))
    out_meshes.sort(key=lambda m: m.role != "body")  # body first
    return SceneDescription(source=str(path), up_axis=up, meters_per_unit=mpu, times=times,
                            time_range=time_range, fps=float(stage.GetTimeCodesPerSecond()),
                            meshes=out_meshes)


def _gltf_scene(path: Path, frames) -> SceneDescription:
    """A ``.glb``/``.gltf`` file as a scene: its first animation (all of it,
    then the frames asked for) sampled at
    the file's frame rate (time code = frame index), else one frame in the
    pose :func:`wearfit_usd.io.gltf.read_gltf_character` reads."""
    char, all_frames, fps, n_total = read_gltf_frames(path)
    times = select_times((0.0, float(n_total - 1)), frames, path)
    mesh_frames = [[fr[int(t)] for t in times] for fr in all_frames]
    order = [char.body] + list(char.items)
    colors = iter(item_colors([m.name for m in char.items]))
    out = []
    for k, (m, fr) in enumerate(zip(order, mesh_frames)):
        role = "body" if k == 0 else "item"
        default = np.asarray(BODY_COLOR if role == "body" else next(colors), dtype=np.float64)
        for i in range(1, len(fr)):  # unchanged frames share one array (the renderer skips re-uploads)
            if np.array_equal(fr[i], fr[i - 1]):
                fr[i] = fr[i - 1]
        authored = m.display_color
        out.append(SceneMesh(name=m.name, path=m.path, role=role, faces=m.faces, frames=fr,
                             color=np.clip(authored, 0, 1) if authored is not None else default,
                             color_authored=authored is not None, skinned=m.is_skinned))
    return SceneDescription(source=str(path), up_axis="Y", meters_per_unit=1.0, times=times,
                            time_range=(0.0, float(n_total - 1)), fps=fps, meshes=out)
