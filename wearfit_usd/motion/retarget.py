"""Retarget BVH motion onto a USD skeleton (rotations transfer, lengths stay).

For every target joint mapped to a clip joint (see :mod:`joint_maps`):

* ``G(f)`` = the clip joint's world rotation at frame f relative to the
  clip's rest (all channels zero; the rest rotations are the identity in
  BVH), a world-space rotation (row-vector 3x3).
* ``Q`` = the per-bone rest correction: the smallest rotation taking the
  clip's rest bone direction (joint -> next mapped joint down the chain) to
  the target's bind bone direction. Joints without a usable bone direction
  (hands with several fingers, zero-length bones) inherit their parent's Q.
* ``mode="posture"`` (default): the limbs as ``"direction"``, the axial
  chain (the joints from the hips up to the head, by the pairing's roles)
  as ``"bind"``. A skeleton's spine, neck and head bones follow its own
  conventions, not a pose: MakeHuman's neck bone leans 22 degrees forward
  in its upright bind pose, CMU's head bone 13 degrees back in its upright
  rest. Pointing the target's bones along the clip's ("direction") imposed
  the clip skeleton's conventions: heads thrown back and torsos leaning
  back in the CMU walk, jump and dances. The clip's rest and the target's
  bind are both a person standing upright, so the axial chain takes the
  clip's rotation relative to its rest: the torso's lean (pelvis to neck,
  from the vertical, against the rest's) is the clip's (median over the
  clip, ref_female: walk 1.0 / 4.9 / -0.6, run 10.5 / 3.5 / 8.8, jump
  4.6 / 9.3 / 4.6 degrees for the clip / "direction" / "posture"). The
  limbs' rest poses differ by pose (a T-pose clip, an A-pose body), so they
  keep the bone directions.
* ``mode="direction"``: ``W(f) = B @ Q.T @ G(f)``: each target
  bone points exactly where the clip's bone points, the twist about the bone
  follows the clip relative to the target's bind frame. Rest-pose
  differences (T-pose clip, A-pose body; CMU's splayed rest legs) do not
  distort the motion: hanging arms hang, walking legs stay under the hips.
  At the clip's rest the body takes the clip's rest *shape* (a T-pose clip's
  rest frame raises the arms).
* ``mode="bind"``: ``W(f) = B @ Q.T @ G(f) @ Q``: the clip's motion relative
  to its rest, applied in the target's bind frame with the rest correction;
  at the clip's rest the body is exactly in its bind pose, but the rest-pose
  difference stays in every frame (measured on cmu_07_01 onto ref_male: with
  the zero rest the feet cross by 24-30 cm because CMU's rest legs splay
  20 degrees; with the T-pose frame as rest the hands hang 29 cm inside the
  torso because the A-pose arms are 48 degrees lower than the T-pose).

Unmapped target joints keep their bind-relative local rotation. Joint
positions come from the target's bind offsets (its bone lengths). The joint
mapped to the clip's root moves with the clip's root translation scaled by
the hip-height ratio (target / clip), starting above the target's bind
position, with the clip's floor put on the target's floor.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, NonFiniteError, OutputError
from ..io.bvh import BVHMotion
from ..model import Skeleton
from ..resources import require_memory
from ..transforms import invert, matrix_from_quat, quat_from_matrix, quat_slerp, rotation_between, rotation_part
from .joint_maps import JointMapping, normalize, roles
from .rig_match import RigMatch, find_roles, leg_length, match_skeletons, require_match

#: retargeting modes (module docstring)
MODES = ("posture", "direction", "bind")


@dataclass
class Retargeted:
    """Per-frame joint transforms of a target skeleton.

    world: (F, J, 4, 4) internal world transforms (metres, Y up), usable as
        ``skinning.skin_mesh(mesh, skeleton, world)``.
    local: (F, J, 4, 4) ``skeleton.local_from_world(world)`` (skeleton units,
        for a UsdSkel SkelAnimation).
    times: (F,) seconds from the first retargeted frame; fps: frames/second.
    source_frames: (F,) the (fractional) clip frame of each output frame.
    """
    world: np.ndarray
    local: np.ndarray
    fps: float
    times: np.ndarray
    joint_names: list[str]
    mapping: JointMapping
    source_frames: np.ndarray
    hip_height_ratio: float
    report: dict = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.world.shape[0])

    def positions(self) -> np.ndarray:
        """(F, J, 3) joint world positions, metres."""
        return self.world[:, :, 3, :3]


def _descendants(parents: np.ndarray) -> list[list[int]]:
    """Per joint, its descendants in breadth-first order."""
    children: list[list[int]] = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    out = []
    for j in range(len(parents)):
        order, queue = [], list(children[j])
        while queue:
            c = queue.pop(0)
            order.append(c)
            queue.extend(children[c])
        out.append(order)
    return out


def _depth(parents):
    d = np.zeros(len(parents), dtype=int)
    for j, p in enumerate(parents):
        d[j] = 0 if p < 0 else d[p] + 1
    return d


def output_frame_count(n: int, src_fps: float, fps: float | None) -> int:
    """Frames :func:`resample_clip` makes of ``n`` clip frames at ``src_fps``
    resampled to ``fps`` (None or equal: ``n``), computed without allocating."""
    if fps is None or abs(fps - src_fps) < 1e-9:
        return int(n)
    count = np.floor((n - 1) / src_fps * fps + 1e-9) + 1
    return int(count) if np.isfinite(count) else np.iinfo(np.int64).max


def resample_clip(grot: np.ndarray, root_pos: np.ndarray, src_fps: float, fps: float):
    """Resample clip world rotations (F, J, 3, 3) by quaternion slerp and root
    positions (F, 3) linearly to ``fps``. Returns (rot, pos, frames) with
    frames (F',) the fractional source frame of each output frame."""
    n = grot.shape[0]
    count = output_frame_count(n, src_fps, fps)
    frames = np.arange(count) * (src_fps / fps)
    frames = np.minimum(frames, n - 1)
    i0 = np.floor(frames).astype(int)
    i1 = np.minimum(i0 + 1, n - 1)
    t = frames - i0
    q = quat_from_matrix(grot)  # (F, J, 4)
    qs = quat_slerp(q[i0], q[i1], np.broadcast_to(t[:, None], (count, grot.shape[1])))
    pos = root_pos[i0] * (1 - t)[:, None] + root_pos[i1] * t[:, None]
    return matrix_from_quat(qs), pos, frames


def retarget(motion: BVHMotion, skeleton: Skeleton, mapping: JointMapping | dict | None = None,
             start: int = 0, end: int | None = None, fps: float | None = None,
             mode: str = "posture", rest="zero", max_frames: int | None = None) -> Retargeted:
    """Retarget ``motion`` onto ``skeleton``.

    mapping: a :class:`JointMapping`, a {target: source} dict (user map
        applied over the automatic one), or None (automatic, by names).
    start, end: clip frame range [start, end) (``start=1`` skips CMU's
        synthetic T-pose frame 0).
    fps: None keeps the clip's rate; otherwise resample (slerp rotations,
        linear root translation).
    mode: "posture" (default: the limbs as "direction", the hips-to-head
        chain as "bind"), "direction" (each target bone points along the
        clip's bone, so a T-pose clip on an A-pose body gives natural
        motion) or "bind" (the clip's rest maps exactly to the target's bind
        pose; the rest-pose difference then persists through the motion);
        see the module docstring.
    rest: the clip's rest pose: "zero" (all channels zero, BVH's rest) or a
        frame index (e.g. 0 for CMU's synthetic T-pose frame).
    max_frames: refuse (:class:`OutputError`) more output frames than this,
        before allocating anything per frame.
    Raises :class:`NonFiniteError` naming the frame and joint when the
    joint transforms are not finite.
    Returns :class:`Retargeted` with (F, J, 4, 4) ``world`` and ``local``.
    """
    return retarget_stream(motion, skeleton, mapping, start, end, fps, mode, rest,
                           max_frames).retargeted()


def retarget_stream(motion: BVHMotion, skeleton: Skeleton, mapping: JointMapping | dict | None = None,
                    start: int = 0, end: int | None = None, fps: float | None = None,
                    mode: str = "posture", rest="zero",
                    max_frames: int | None = None) -> RetargetStream:
    """Set up the retargeting of ``motion`` onto ``skeleton`` (arguments,
    checks and errors as :func:`retarget`) without computing any output
    frame: a :class:`RetargetStream` computes them a block at a time, so
    memory does not grow with the frame count."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    n_all = motion.n_frames
    end = n_all if end is None else int(end)
    start = int(start)
    if start < 0 or end > n_all or start >= end:
        raise InputError(motion.path, f"frame range [{start}, {end}) is empty or outside the clip's "
                                      f"{n_all} frames")
    if fps is not None and not (fps > 0 and np.isfinite(fps)):
        raise InputError(motion.path, f"fps must be > 0 and finite, got {fps}")
    tnames = list(skeleton.joint_names)
    n_out = output_frame_count(end - start, motion.fps, fps)
    if max_frames is not None and n_out > max_frames:
        raise OutputError(motion.path, f"the shot would have {n_out} frames ({end - start} clip frames "
                                       f"of {motion.frame_time:g} s at {fps or motion.fps:g} fps), more "
                                       f"than the limit of {max_frames} (raise it with --max-frames)")
    require_memory((end - start) * 32 + n_out * 8, f"retargeting {n_out} frames")  # root path
    match = None
    if mapping is None or isinstance(mapping, dict):
        try:
            match = match_clip(motion, skeleton, user_map=mapping)
        except KeyError as exc:  # a user map naming joints the clip or skeleton lacks
            raise InputError(motion.path, f"joint map: {exc.args[0]} (skeleton {skeleton.path or ''})") from None
        if not mapping:  # a user's joint map overrides the key-role requirement
            require_match(match, motion.path, skeleton.path or "<target skeleton>",
                          "retargeting the clip",
                          "pair them with a JSON joint map {target joint: clip joint} (--map)")
        mapping = match.mapping
    sidx = {n: i for i, n in enumerate(motion.joint_names)}
    tparents = np.asarray(skeleton.parents)
    J = len(tnames)
    src_of = np.full(J, -1, dtype=int)
    for t, s in mapping.pairs.items():
        if t in tnames and s in sidx:
            src_of[tnames.index(t)] = sidx[s]
    if not (src_of >= 0).any():
        raise InputError(motion.path, f"no joint of the clip maps onto the skeleton "
                                      f"{skeleton.path or ''} (clip joints e.g. "
                                      f"{motion.joint_names[:5]}, skeleton joints e.g. {tnames[:5]}); "
                                      "give a JSON joint map")
    sroot = int(np.flatnonzero(motion.parents < 0)[0])
    # target joint that carries the root translation: mapped to the clip root,
    # else the shallowest mapped joint
    mapped = np.flatnonzero(src_of >= 0)
    troot_cand = [t for t in mapped if src_of[t] == sroot]
    tdepth = _depth(tparents)
    troot = troot_cand[0] if troot_cand else int(mapped[np.argmin(tdepth[mapped])])
    if match is not None and "hips" in match.source.roles and "hips" in match.target.roles:
        # a clip root above the hips (``joint_Root`` on the floor): the hips
        # carry the translation, as on the target
        sh, th = match.source.roles["hips"], match.target.roles["hips"]
        if sh != sroot and src_of[th] == sh:
            troot = th

    # ---- clip kinematics: one pass over the source frames in blocks for
    # the finite check and the clip floor; per output frame nothing is kept
    # but the (F, 3) root path
    # the clip joint that drives the target's root carrier: the clip root, or
    # the hips below a floor-level root joint (``joint_Root``)
    s_carrier = int(src_of[troot])
    src_fps = motion.fps
    same_rate = fps is None or abs(fps - src_fps) < 1e-9
    out_fps = src_fps if same_rate else float(fps)
    n_src = end - start
    root_src = np.empty((n_src, 3))
    floor_c = np.inf
    for a in range(0, n_src, BLOCK):
        b = min(a + BLOCK, n_src)
        grot_b, gpos_b = motion.global_rotations_positions(np.arange(start + a, start + b))
        bad = ~(np.isfinite(grot_b).all(axis=(-2, -1)) & np.isfinite(gpos_b).all(axis=-1))
        if bad.any():
            f, j = (int(v) for v in np.argwhere(bad)[0])
            raise NonFiniteError(motion.path, f"clip frame {start + a + f}, joint {motion.joint_names[j]}: "
                                              "non-finite joint transform (extreme values in the clip?)")
        root_src[a:b] = gpos_b[:, s_carrier]
        floor_c = min(floor_c, float(gpos_b[..., 1].min()))
    F = n_out
    if same_rate:
        src_frames = np.arange(start, end).astype(float)
    else:
        src_frames = start + np.minimum(np.arange(F) * (src_fps / out_fps), n_src - 1)

    # ---- rest data
    if rest == "zero":
        srest = motion.rest_global_transforms()[:, 3, :3]  # (Js, 3)
        r0 = None
    else:
        r0, p0 = motion.global_rotations_positions([int(rest)])
        r0, srest = r0[0], p0[0]

    bind = np.asarray(skeleton.bind_world, dtype=np.float64)
    bpos = bind[:, 3, :3]

    # ---- per-bone rest correction Q (world, row-vector: d_clip @ Q = d_target)
    desc = _descendants(tparents)
    Q = np.broadcast_to(np.eye(3), (J, 3, 3)).copy()
    has_dir = np.zeros(J, dtype=bool)
    for t in range(J):
        if src_of[t] < 0:
            continue
        side_t = normalize(tnames[t])[0]
        cands = [d for d in desc[t] if src_of[d] >= 0]
        # prefer joints on the same side / the centre line, then shallow ones
        cands.sort(key=lambda d: (normalize(tnames[d])[0] != side_t, tdepth[d]))
        for d in cands:
            vt = bpos[d] - bpos[t]
            vs = srest[src_of[d]] - srest[src_of[t]]
            if np.linalg.norm(vt) > 1e-3 and np.linalg.norm(vs) > 1e-3:
                Q[t] = rotation_between(vs, vt)
                has_dir[t] = True
                break
    for t in range(J):  # inherit the parent's correction (parents come first)
        if not has_dir[t] and tparents[t] >= 0:
            Q[t] = Q[tparents[t]]

    # ---- hip heights and floors
    floor_t = float(bpos[:, 1].min())
    hh_t = float(bpos[troot, 1] - floor_t)
    # clip: leg length in the rest pose, measured like the target's bind pose
    # (root height above the lowest joint), made robust to splayed rest legs
    # by using the chain lengths of the mapped leg
    hh_c = _clip_hip_height(motion, srest, s_carrier)
    tfoot = _find_foot(tnames, tparents, troot)
    if tfoot is not None:
        hh_t = _chain_height(bpos, tparents, troot, tfoot)
    ratio = hh_t / hh_c if hh_c > 1e-6 else 1.0
    # strides scale with the legs: the horizontal travel by the leg-length ratio
    ratio_xz = ratio
    if match is not None:
        lt, lc = leg_length(match.target, bpos), leg_length(match.source, srest)
        if lt and lc:
            ratio_xz = lt / lc
    # the joints that keep the target's bind posture (see the module docstring)
    posture = np.zeros(J, dtype=bool)
    if mode == "bind":
        posture[:] = True
    elif mode == "posture":
        # the roles of the pairing, or (a JointMapping given) of the skeleton alone
        troles = match.target if match is not None else find_roles(tnames, tparents, bpos)
        posture[axial_chain(troles.roles, tparents)] = True
    return RetargetStream(motion=motion, skeleton=skeleton, mapping=mapping, mode=mode, fps=out_fps,
                          posture=posture,
                          n_frames=F, start=start, same_rate=same_rate, src_fps=src_fps,
                          source_frames=src_frames, root_src=root_src, floor_c=floor_c, r0=r0,
                          src_of=src_of, troot=troot, Q=Q, ratio=ratio, floor_t=floor_t, ratio_xz=ratio_xz,
                          match=match)


def axial_chain(roles: dict, parents: np.ndarray) -> list[int]:
    """Joints from the hips up to the head (both included), by a skeleton's
    roles ({role: joint index}, :class:`rig_match.RigRoles`); empty when
    either is missing or the head is not above the hips."""
    if "hips" not in roles or "head" not in roles:
        return []
    hips, j, chain = roles["hips"], roles["head"], []
    while j >= 0:
        chain.append(int(j))
        if j == hips:
            return chain
        j = int(parents[j])
    return []


#: output frames computed at once by :class:`RetargetStream` (and source
#: frames per block in its first pass): memory does not grow with the clip
BLOCK = 512


@dataclass
class RetargetStream:
    """A retargeted clip computed on demand, a block of output frames at a
    time (:meth:`world`, :meth:`local`), so that memory stays flat however
    long the shot; :meth:`retargeted` computes every frame at once. Made by
    :func:`retarget_stream`; the fields are its set-up (rest correction Q,
    hip-height ratio, floors, the clip's (F_src, 3) root path)."""
    motion: BVHMotion
    skeleton: Skeleton
    mapping: JointMapping
    mode: str
    fps: float
    n_frames: int
    start: int
    same_rate: bool
    src_fps: float
    source_frames: np.ndarray
    root_src: np.ndarray
    floor_c: float
    r0: np.ndarray | None
    src_of: np.ndarray
    troot: int
    Q: np.ndarray
    ratio: float
    floor_t: float
    posture: np.ndarray  # (J,) bool: joints retargeted relative to the bind pose (mode)
    ratio_xz: float = 1.0          # horizontal travel: the leg-length ratio
    match: RigMatch | None = None  # the role pairing, when the mapping came from it
    # feet on the floor (motion.floor.place_on_floor): every frame moves up by
    # floor_dy, less floor_slope (2,) x the carrier's horizontal travel since
    # frame 0 (floor_ground0 (2,)) where a tilted capture floor was levelled
    floor_dy: float = 0.0
    floor_slope: np.ndarray | None = None
    floor_ground0: np.ndarray | None = None

    @property
    def joint_names(self) -> list[str]:
        return list(self.skeleton.joint_names)

    @property
    def report(self) -> dict:
        report = self.match.report() if self.match is not None else self.mapping.report()
        if self.floor_dy or self.floor_slope is not None:
            report["floor_shift_m"] = self.floor_dy
            slope = 0.0 if self.floor_slope is None else float(np.linalg.norm(self.floor_slope))
            report["floor_tilt_deg"] = float(np.degrees(np.arctan(slope)))
        report.update({"mode": self.mode, "hip_height_ratio": self.ratio, "travel_ratio": self.ratio_xz,
                       "root_joint": self.joint_names[self.troot], "frames": self.n_frames,
                       "fps": self.fps, "source_range": [self.start, self.start + len(self.root_src)]})
        return report

    def _clip(self, a: int, b: int):
        """Clip world rotations (b-a, Js, 3, 3) and root positions (b-a, 3)
        of output frames [a, b), resampled when the rates differ."""
        n = len(self.root_src)
        if self.same_rate:
            grot, _ = self.motion.global_rotations_positions(np.arange(self.start + a, self.start + b))
            root = self.root_src[a:b]
        else:
            frames = np.minimum(np.arange(a, b) * (self.src_fps / self.fps), n - 1)
            i0 = np.floor(frames).astype(int)
            i1 = np.minimum(i0 + 1, n - 1)
            t = frames - i0
            lo, hi = int(i0.min()), int(i1.max()) + 1
            g, _ = self.motion.global_rotations_positions(np.arange(self.start + lo, self.start + hi))
            q = quat_from_matrix(g)  # (hi-lo, Js, 4)
            qs = quat_slerp(q[i0 - lo], q[i1 - lo], np.broadcast_to(t[:, None], (b - a, g.shape[1])))
            grot = matrix_from_quat(qs)
            root = self.root_src[i0] * (1 - t)[:, None] + self.root_src[i1] * t[:, None]
        if self.r0 is not None:
            grot = np.swapaxes(self.r0, -1, -2)[None] @ grot  # relative to that rest
        return grot, root

    def world(self, a: int = 0, b: int | None = None) -> np.ndarray:
        """(b-a, J, 4, 4) internal world joint transforms of output frames [a, b)."""
        b = self.n_frames if b is None else min(int(b), self.n_frames)
        a = int(a)
        grot, root_pos = self._clip(a, b)
        root0 = self.root_src[0]  # output frame 0 is the first clip frame (as resampled)
        if not self.same_rate:
            root0 = self.root_src[0] * 1.0 + self.root_src[min(1, len(self.root_src) - 1)] * 0.0
        skeleton, Q, posture = self.skeleton, self.Q, self.posture
        tparents = np.asarray(skeleton.parents)
        bind = np.asarray(skeleton.bind_world, dtype=np.float64)
        bpos = bind[:, 3, :3]
        bscale = np.linalg.norm(bind[:, :3, :3], axis=-1).mean(axis=-1)  # (J,) uniform scale
        brot = rotation_part(bind)  # (J, 3, 3)
        F, J = b - a, len(tparents)
        ratio, floor_t, floor_c = self.ratio, self.floor_t, self.floor_c
        W = np.empty((F, J, 4, 4))
        W[..., 3] = [0.0, 0.0, 0.0, 1.0]
        rot = np.empty((F, J, 3, 3))
        pos = np.empty((F, J, 3))
        inv_bind = invert(bind)
        for t in range(J):
            p = tparents[t]
            s = self.src_of[t]
            if s >= 0:
                g = grot[:, s]
                if posture[t]:
                    rot[:, t] = brot[t] @ Q[t].T @ g @ Q[t]
                else:
                    rot[:, t] = brot[t] @ Q[t].T @ g
            elif p >= 0:
                rot[:, t] = (brot[t] @ brot[p].T) @ rot[:, p]
            else:
                rot[:, t] = brot[t]
            if t == self.troot:
                d = root_pos - root0
                pos[:, t, 0] = bpos[t, 0] + self.ratio_xz * d[:, 0]
                pos[:, t, 2] = bpos[t, 2] + self.ratio_xz * d[:, 2]
                pos[:, t, 1] = floor_t + ratio * (root_pos[:, 1] - floor_c)
            elif p >= 0:
                off = (bind[t] @ inv_bind[p])[3, :3]  # bind offset in the parent's frame
                pos[:, t] = np.einsum("i,fij->fj", off, W[:, p, :3, :3]) + pos[:, p]
            else:
                pos[:, t] = bpos[t]
            W[:, t, :3, :3] = bscale[t] * rot[:, t]
            W[:, t, 3, :3] = pos[:, t]
            W[:, t, :3, 3] = 0.0
        if self.floor_slope is not None:
            W[:, :, 3, 1] -= ((W[:, self.troot, 3][:, [0, 2]] - self.floor_ground0) @ self.floor_slope)[:, None]
        if self.floor_dy:
            W[:, :, 3, 1] += self.floor_dy
        check_finite_transforms(W, self.source_frames[a:b], self.joint_names, self.motion.path, first=a)
        return W

    def local(self, a: int = 0, b: int | None = None, world: np.ndarray | None = None) -> np.ndarray:
        """(b-a, J, 4, 4) ``skeleton.local_from_world`` of :meth:`world` (pass
        ``world`` when already computed)."""
        return self.skeleton.local_from_world(self.world(a, b) if world is None else world)

    def blocks(self, size: int = BLOCK):
        """(a, b) output frame ranges of at most ``size`` frames."""
        return [(a, min(a + size, self.n_frames)) for a in range(0, self.n_frames, size)]

    def retargeted(self) -> Retargeted:
        """Every frame at once, as :func:`retarget` returns it."""
        # world, local, their inverses, rotations, positions and the clip's
        # block: about 7 (J, 4, 4) float64 arrays per frame
        require_memory(self.n_frames * len(self.src_of) * 7 * 128,
                       f"retargeting {self.n_frames} frames at once")
        W = self.world(0, self.n_frames)
        local = self.skeleton.local_from_world(W)
        F, out_fps = self.n_frames, self.fps
        return Retargeted(world=W, local=local, fps=out_fps, times=np.arange(F) / out_fps,
                          joint_names=self.joint_names, mapping=self.mapping,
                          source_frames=self.source_frames, hip_height_ratio=self.ratio,
                          report=self.report)


def check_finite_transforms(world: np.ndarray, source_frames: np.ndarray, joint_names, path,
                            first: int = 0) -> None:
    """Raise :class:`NonFiniteError` naming the first frame and joint whose
    (F, J, 4, 4) transform holds NaN/inf or is singular (zero scale);
    ``first`` is the output frame number of ``world[0]``."""
    ok = np.isfinite(world).all(axis=(-2, -1))
    if ok.all():
        scale = np.abs(world[..., :3, :3]).max(axis=(-2, -1))
        ok = scale > 1e-12
        if ok.all():
            return
    f, j = (int(v) for v in np.argwhere(~ok)[0])
    raise NonFiniteError(path, f"retargeting gave a non-finite or singular transform at output frame {first + f} "
                               f"(clip frame {float(source_frames[f]):g}), joint {joint_names[j]} "
                               "(extreme values in the clip or the skeleton?)")


def match_clip(motion: BVHMotion, skeleton: Skeleton, user_map: dict | None = None) -> RigMatch:
    """Pair a clip's joints with a skeleton's (names as hints, then the rest
    pose's structure: :func:`~wearfit_usd.motion.rig_match.match_skeletons`).

    Parameters
    ----------
    motion : the clip (its rest pose: all channels zero).
    skeleton : the target (its bind positions).
    user_map : {target joint: clip joint or None} overriding the pairs.

    Returns
    -------
    :class:`~wearfit_usd.motion.rig_match.RigMatch`.
    """
    return match_skeletons(motion.joint_names, motion.parents, motion.rest_global_transforms()[:, 3, :3],
                           skeleton.joint_names, skeleton.parents, skeleton.bind_positions(),
                           user_map=user_map)


def _clip_hip_height(motion: BVHMotion, rest: np.ndarray, root: int) -> float:
    """Standing hip height of the clip skeleton (m): vertical root offset to
    the thigh plus the thigh, shin and foot chain lengths, so a rest pose
    with splayed legs (CMU) is not under-estimated."""
    foot = _find_foot(motion.joint_names, motion.parents, root)
    if foot is None:
        return float(rest[root, 1] - rest[:, 1].min())
    return _chain_height(rest, motion.parents, root, foot)


def _find_foot(names, parents, root):
    """Index of the lowest-level joint of a leg in the rest pose below the
    root: the deepest joint of the leg subtree before the toes (by role)."""
    r = roles(names)
    for key in ("foot_l", "foot_r"):
        if key in r:
            return names.index(r[key])
    return None


def _chain_height(pos, parents, root, foot) -> float:
    """root height above the foot's lowest descendant, with the leg bones
    (root .. foot) stretched straight down: vertical root->first leg joint
    offset + sum of bone lengths + foot height above its lowest descendant."""
    chain = []
    j = foot
    while j != root and j >= 0:
        chain.append(j)
        j = parents[j]
    if j != root:
        return float(pos[root, 1] - pos[:, 1].min())
    chain = chain[::-1]  # first leg joint .. foot
    seg = 0.0
    first = None
    for a, b in zip(chain[:-1], chain[1:]):
        length = float(np.linalg.norm(pos[b] - pos[a]))
        if first is None and length > 1e-6:
            first = a
        seg += length
    first = chain[0] if first is None else first
    top = float(pos[root, 1] - pos[first, 1])
    below = [d for d in range(len(parents)) if _is_desc(parents, d, foot)]
    foot_h = float(pos[foot, 1] - min([pos[d, 1] for d in below] + [pos[foot, 1]]))
    return top + seg + foot_h


def _is_desc(parents, d, a) -> bool:
    j = parents[d]
    while j >= 0:
        if j == a:
            return True
        j = parents[j]
    return False
