"""Write an animated shot: the target body with its SkelAnimation and each
item as a Mesh with time-sampled points (and extent, optionally normals and
velocities), streamed frame by frame.

Layout of the written stage (default prim ``/Root``)::

    /Root                      Xform
      /Character               SkelRoot
        /Skeleton              Skeleton, skel:animationSource -> </Root/Character/Animation>
        /Animation             SkelAnimation (translations, rotations, scales; time-sampled)
        /Body                  Mesh, skinned (UsdSkel poses it)
        /<item>                skinned items (``--mode lbs``)
      /Items                   Xform
        /<item>                Mesh with time-sampled points + extent

For long shots, ``clip_frames=N`` writes item samples into value-clip layers
of N frames each (``<shot>.clips/items.<k>.usdc``) that are saved and released
as soon as they are full, so memory stays bounded and crate writing fast
(many samples on one attribute slow it down badly).
"""
from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ..errors import OutputError
from ..geometry.closest import VertexNormals
from ..model import Character, Mesh
from ..transforms import decompose, quat_from_matrix, transform_points
from .usd import save_layer
from .usd_author import (
    StageLayout,
    author_body,
    author_mesh_topology,
    author_skeleton,
    author_static_item,
    prim_name,
    vt_extent,
    vt_points,
)
from .usd_carry import CarryPlan, carry

#: the value-clip layers the writer makes in ``<shot>.clips/``; nothing else
#: in that folder is ever replaced or deleted
CLIP_NAME = re.compile(r"items\.\d{4,}\.usdc")


class ShotWriter:
    """Stream an animated shot to ``path``.

    target: the character whose body and skeleton are written (internal
    space); items: meshes (internal space, reference topology) whose points
    are given per frame by :meth:`write_frame`; ``fps``: output frame rate
    (timeCodesPerSecond = framesPerSecond = fps); frames are time codes
    0..n_frames-1. ``skinned_items``: items with joint influences written as
    skinned meshes in the SkelRoot instead of point caches. ``carry_plan``:
    the inputs' materials, primvars, subsets and attributes carried onto the
    written meshes (:mod:`.usd_carry`). ``skeleton``: the skeleton to write
    when it is the target's with joints appended (the items' own joints,
    :mod:`animate.item_joints`); their transforms come per frame through
    :meth:`write_item_joints`, the body's through :meth:`write_animation`.

    Use as a context manager; nothing appears at ``path`` unless the block
    completes (temporary file + rename).
    """

    def __init__(self, path, target: Character, items: list[Mesh], fps: float, n_frames: int,
                 clip_frames: int | None = None, velocities: bool = False,
                 skinned_items: list[Mesh] | None = None, up_axis: str | None = None,
                 meters_per_unit: float | None = None, carry_plan: CarryPlan | None = None,
                 skeleton=None):
        self._tmp = None
        self._clip_dir_tmp = None
        self.stage = None
        self._clip_stage = None
        try:
            self._start(path, target, items, fps, n_frames, clip_frames, velocities, skinned_items,
                        up_axis, meters_per_unit, carry_plan, skeleton)
        except BaseException:
            self.abort()
            raise

    def _start(self, path, target, items, fps, n_frames, clip_frames, velocities, skinned_items,
               up_axis, meters_per_unit, carry_plan=None, skeleton=None):
        from pxr import Usd, UsdGeom, UsdSkel
        self.path = Path(path)
        self.fps = float(fps)
        self.n_frames = int(n_frames)
        self.items = list(items)
        self.velocities = velocities
        self.clip_frames = int(clip_frames) if clip_frames else None
        self.target = target
        self._written = np.zeros(self.n_frames, dtype=bool)
        self._anim_written = np.zeros(self.n_frames, dtype=bool)
        if self.clip_frames is not None and self.clip_frames < 1:
            raise ValueError(f"clip_frames must be >= 1, got {clip_frames}")
        self._clip_dir_final = self.path.parent / f"{self.path.stem}.clips"
        if self.clip_frames and self._clip_dir_final.exists() and not self._clip_dir_final.is_dir():
            raise OutputError(self._clip_dir_final, "exists and is not a folder: cannot write the "
                                                    "shot's value clips there")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=self.path.suffix or ".usdc",
                                   dir=str(self.path.parent))
        os.close(fd)
        os.unlink(tmp)
        self._tmp = tmp
        if self.clip_frames:
            self._clip_dir_tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.stem}.clips.",
                                                       dir=str(self.path.parent)))
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(self._clip_dir_tmp, 0o777 & ~umask)  # mkdtemp makes it private
        self.stage = Usd.Stage.CreateNew(tmp)
        up = up_axis or target.up_axis
        mpu = meters_per_unit or target.meters_per_unit
        self.layout = StageLayout(self.stage, up, mpu)
        UsdSkel.Root.Define(self.stage, self.layout.skel_root)
        self._skel_out = None
        self._written_skel = target.skeleton
        if skeleton is not None:
            body = target.skeleton
            if (body is None or skeleton.n_joints < body.n_joints
                    or list(skeleton.joint_paths[:body.n_joints]) != list(body.joint_paths)):
                raise ValueError("the skeleton to write must be the target's with joints appended")
            self._written_skel = skeleton
        self._pending = {}  # frame -> body joints' world transforms awaiting the item joints'
        if self._written_skel is not None:
            _, self._skel_out = author_skeleton(self.layout, self._written_skel)
        author_body(self.layout, target.body, target.skeleton)
        UsdGeom.Xform.Define(self.stage, self.layout.items_path)
        self._item_prims = []
        self._normals = [VertexNormals(m.faces, m.n_points) for m in self.items]
        names = set()
        for item in self.items:
            name = prim_name(item.name)
            while name in names:
                name += "_"
            names.add(name)
            ipath = self.layout.items_path.AppendChild(name)
            mesh = UsdGeom.Mesh.Define(self.stage, ipath)
            pts = transform_points(item.points, self.layout.from_internal)
            author_mesh_topology(mesh, item)
            if not self.clip_frames:
                # default = reference shape, for tools that read without a time
                # code (a default in the shot layer would hide value clips)
                mesh.CreatePointsAttr(vt_points(pts))
                mesh.CreateExtentAttr(vt_extent(pts))
            self._item_prims.append(ipath)
        self.skinned_items = list(skinned_items or [])
        carried = [(m.name, p) for m, p in zip(self.items, self._item_prims)]
        for item in self.skinned_items:
            carried.append((item.name, author_static_item(self.layout, item, target.skeleton).GetPath()))
        carry(carry_plan, self.stage, self.path, self.layout.body_path, carried)
        self.stage.SetStartTimeCode(0)
        self.stage.SetEndTimeCode(max(self.n_frames - 1, 0))
        self.stage.SetTimeCodesPerSecond(self.fps)
        self.stage.SetFramesPerSecond(self.fps)
        self._prev = None  # (frame, [points_stage]) for velocities (one-frame delay)
        self._prev_vel = None
        self._attr_stage = None   # stage the cached attributes belong to
        self._attr_cache = []
        self._clip_layer = None
        self._clip_index = -1
        self._clip_stage = None
        self._clip_paths = []

    # ------------------------------------------------------------------
    def write_animation(self, local: np.ndarray, first_frame: int | None = None) -> None:
        """Author the SkelAnimation from (F, J, 4, 4) joint transforms local to
        their parents, as :meth:`Skeleton.local_from_world` of the target
        skeleton returns them (target skeleton space): every frame at once,
        or with ``first_frame`` a block of frames from that time code on
        (blocks may come in any order; together they must cover the shot)."""
        skel = self.target.skeleton
        if skel is None:
            raise ValueError("target has no skeleton: cannot write a SkelAnimation")
        local = np.asarray(local, dtype=np.float64)
        if first_frame is None:
            if local.shape[0] != self.n_frames:
                raise ValueError(f"animation has {local.shape[0]} frames, shot has {self.n_frames}")
            first_frame = 0
        elif not 0 <= first_frame <= self.n_frames - local.shape[0]:
            raise ValueError(f"animation frames {first_frame}..{first_frame + local.shape[0] - 1} "
                             f"outside the shot's {self.n_frames}")
        world = skel.world_from_local(local)
        if self._written_skel.n_joints > skel.n_joints:
            # the items' joints come with the frame's redress (write_item_joints)
            for f in range(local.shape[0]):
                self._pending[first_frame + f] = world[f]
            return
        self._author_animation(world, first_frame)

    def write_item_joints(self, frame: int, world: np.ndarray) -> None:
        """Author frame ``frame`` of the SkelAnimation with the (n, 4, 4)
        internal world transforms of the joints appended to the target's
        skeleton (after :meth:`write_animation` gave the body's)."""
        n = self._written_skel.n_joints - self.target.skeleton.n_joints
        world = np.asarray(world, dtype=np.float64)
        if n <= 0 or world.shape != (n, 4, 4):
            raise ValueError(f"{world.shape} item joint transforms for {max(n, 0)} item joints")
        if frame not in self._pending:
            raise ValueError(f"item joints of frame {frame} before its body joints")
        body = self._pending.pop(frame)
        self._author_animation(np.concatenate([body, world])[None], frame)
        self._anim_written[frame] = True

    def _author_animation(self, world: np.ndarray, first_frame: int) -> None:
        """Author (F, J_written, 4, 4) internal world joint transforms from time code ``first_frame`` on."""
        from pxr import UsdSkel, Vt
        # re-express in the written skeleton's space (identity skeleton xform)
        out_local = self._skel_out.local_from_world(world)
        t, r, s = decompose(out_local)
        q = quat_from_matrix(r)  # (F, J, 4) w,x,y,z
        if getattr(self, "_anim_attrs", None) is None:
            anim = UsdSkel.Animation.Define(self.stage, self.layout.anim_path)
            anim.CreateJointsAttr(Vt.TokenArray(self._written_skel.joint_paths))
            self._anim_attrs = (anim.CreateTranslationsAttr(), anim.CreateRotationsAttr(),
                                anim.CreateScalesAttr())
            binding = UsdSkel.BindingAPI.Apply(self.stage.GetPrimAtPath(self.layout.skel_path))
            binding.CreateAnimationSourceRel().SetTargets([self.layout.anim_path])
        ta, ra, sa = self._anim_attrs
        # Vt.QuatfArray.FromNumpy takes (imaginary i, j, k, real)
        qf = np.ascontiguousarray(q[..., [1, 2, 3, 0]].astype(np.float32))
        for f in range(world.shape[0]):
            ta.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(t[f], dtype=np.float32)), first_frame + f)
            ra.Set(Vt.QuatfArray.FromNumpy(qf[f]), first_frame + f)
            sa.Set(Vt.Vec3hArray.FromNumpy(np.ascontiguousarray(s[f], dtype=np.float16)), first_frame + f)

    # ------------------------------------------------------------------
    def _target_layer_for(self, frame: int):
        """Stage to author frame samples on (the shot or the current clip)."""
        if not self.clip_frames:
            return self.stage
        k = frame // self.clip_frames
        if k != self._clip_index:
            self._close_clip()
            from pxr import Usd
            self._clip_index = k
            name = f"items.{k:04d}.usdc"
            path = self._clip_dir_tmp / name
            st = Usd.Stage.CreateNew(str(path))
            for ipath in self._item_prims:
                st.OverridePrim(ipath)
            self._clip_stage = st
            self._clip_paths.append(name)
        return self._clip_stage

    def _close_clip(self):
        if self._clip_stage is not None:
            save_layer(self._clip_stage.GetRootLayer(), self._clip_dir_final / self._clip_paths[-1])
            self._clip_stage = None

    def write_frame(self, frame: int, item_points: list[np.ndarray]) -> None:
        """Author item points (internal space, one (M_i, 3) array per item)
        at time code ``frame``. Frames must come in increasing order."""
        if len(item_points) != len(self.items):
            raise ValueError(f"{len(item_points)} point arrays for {len(self.items)} items")
        pts = [transform_points(np.asarray(p, np.float64), self.layout.from_internal) for p in item_points]
        if self.velocities:
            if self._prev is not None:
                pf, pp = self._prev
                vel = [(b - a) * self.fps / max(frame - pf, 1) for a, b in zip(pp, pts)]
                self._author(pf, pp, vel)  # forward difference for the previous frame
                self._prev_vel = vel
            self._prev = (frame, pts)
        else:
            self._author(frame, pts, None)

    def _attributes(self, stage):
        """Per item: (points, extent, normals or None, velocities or None)
        attributes on ``stage`` (the shot or the current clip layer), created
        once per stage."""
        from pxr import UsdGeom
        if self._attr_stage is stage:
            return self._attr_cache
        out = []
        for item, ipath in zip(self.items, self._item_prims):
            mesh = UsdGeom.Mesh(stage.GetPrimAtPath(ipath))
            if not mesh:
                mesh = UsdGeom.Mesh(stage.OverridePrim(ipath))
            na = None
            if item.normals_interpolation is not None:
                na = mesh.CreateNormalsAttr()
                mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
            va = mesh.CreateVelocitiesAttr() if self.velocities else None
            # Create*Attr: a spec in this layer (a schema attribute is valid without one)
            attrs = (mesh.CreatePointsAttr(), mesh.CreateExtentAttr(), na, va)
            out.append(tuple(None if a is None else a.GetPath() for a in attrs))
        # samples go straight into the layer (the attributes' specs exist now)
        self._attr_stage, self._attr_cache = stage, (stage.GetEditTarget().GetLayer(), out)
        return self._attr_cache

    def _author(self, frame, pts, vel):
        from pxr import Sdf
        stage = self._target_layer_for(frame)
        layer, paths = self._attributes(stage)
        # Sdf-level time samples in one change block: the stage processes one
        # change notice per frame instead of one per attribute (2-3x faster)
        with Sdf.ChangeBlock():
            for i, (item, p, (pa, ea, na, va)) in enumerate(zip(self.items, pts, paths)):
                layer.SetTimeSample(pa, frame, vt_points(p))
                layer.SetTimeSample(ea, frame, vt_extent(p))
                if na is not None:
                    n = self._normals[i](p) * (-1 if item.left_handed else 1)
                    layer.SetTimeSample(na, frame, vt_points(n))
                if vel is not None:
                    layer.SetTimeSample(va, frame, vt_points(vel[i]))
        self._written[frame] = True

    # ------------------------------------------------------------------
    def _flush_velocities(self):
        if self.velocities and self._prev is not None:
            pf, pp = self._prev
            # last frame: backward difference (the previous frame's estimate)
            vel = self._prev_vel if self._prev_vel is not None else [np.zeros_like(p) for p in pp]
            self._author(pf, pp, vel)
            self._prev = None

    def close(self) -> Path:
        """Finish, save and move the shot into place; returns its path."""
        from pxr import Sdf, Vt
        self._flush_velocities()
        self._close_clip()
        if not self._written.all():
            missing = np.flatnonzero(~self._written)
            raise ValueError(f"frames never written: {missing[:10].tolist()}")
        if self._written_skel is not None and self.target.skeleton is not None and \
                self._written_skel.n_joints > self.target.skeleton.n_joints and not self._anim_written.all():
            missing = np.flatnonzero(~self._anim_written)
            raise ValueError(f"item joints never written for frames {missing[:10].tolist()}")
        layer = self.stage.GetRootLayer()
        if self.clip_frames:
            # authored on the layer with no stage open on it: a stage would try
            # to open the clips at their final place (not there yet) and warn
            # "Unable to open clip layer" once per clip (FindOrOpen: a strong
            # reference, the layer outlives the stage)
            layer = Sdf.Layer.FindOrOpen(layer.identifier)
            self.stage = None
            self.layout.stage = None
            self._attr_stage = None
            self._attr_cache = []
            clip_rel = f"./{self._clip_dir_final.name}"
            assets = [Sdf.AssetPath(f"{clip_rel}/{n}") for n in self._clip_paths]
            active = [(float(k * self.clip_frames), float(k)) for k in range(len(assets))]
            times = []
            for k in range(len(assets)):
                a = k * self.clip_frames
                b = min(self.n_frames - 1, (k + 1) * self.clip_frames - 1)
                times += [(float(a), float(a)), (float(b), float(b))]
            # the dictionary Usd.ClipsAPI's setters author
            layer.GetPrimAtPath(self.layout.items_path).SetInfo("clips", {"default": {
                "assetPaths": Sdf.AssetPathArray(assets), "primPath": str(self.layout.items_path),
                "active": Vt.Vec2dArray(active), "times": Vt.Vec2dArray(times)}})
            # each item mesh's points have samples only in the clips: author
            # the topology/rest points in the shot layer as fallback.
        save_layer(layer, self.path)
        self.layout.stage = None
        if self.clip_frames:
            self._install_clips()
        os.replace(self._tmp, self.path)
        self._tmp = None
        self.stage = None
        return self.path

    def _install_clips(self) -> None:
        """Move the new clip layers into ``<shot>.clips/``: a folder made by
        the tool (holding only its ``items.NNNN.usdc`` layers) is replaced
        whole; in any other folder only those layers are replaced (stale ones
        from a longer earlier shot removed) and every other file is kept."""
        final = self._clip_dir_final
        if not final.exists():
            os.replace(self._clip_dir_tmp, final)
            self._clip_dir_tmp = None
            return
        new = set(self._clip_paths)
        for p in final.iterdir():
            if CLIP_NAME.fullmatch(p.name) and p.name not in new and p.is_file():
                p.unlink()
        for name in self._clip_paths:
            os.replace(Path(self._clip_dir_tmp) / name, final / name)
        shutil.rmtree(self._clip_dir_tmp, ignore_errors=True)
        self._clip_dir_tmp = None

    def abort(self) -> None:
        """Drop everything written so far (temporary shot file and clip folder)."""
        self.stage = None
        self._clip_stage = None
        if getattr(self, "layout", None) is not None:
            self.layout.stage = None
        self._attr_stage = None
        self._attr_cache = []
        if self._tmp and os.path.exists(self._tmp):
            os.unlink(self._tmp)
        self._tmp = None
        if self._clip_dir_tmp and Path(self._clip_dir_tmp).exists():
            shutil.rmtree(self._clip_dir_tmp, ignore_errors=True)
        self._clip_dir_tmp = None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self.close()
            except BaseException:
                self.abort()
                raise
        else:
            self.abort()
        return False
