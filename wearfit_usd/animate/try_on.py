"""Dynamic try-on: a BVH clip onto a target body wearing the reference's items.

Pipeline (:func:`animate`):

1. retarget the clip onto the target skeleton (:mod:`retarget`), at the
   output frame rate;
2. skin the target body per frame (LBS, :mod:`skinning`);
3. dress frame 0: pose the reference body into frame 0's pose through its own
   rig, fit it onto the target at frame 0 (:mod:`body_fit`) and redress the
   items (:mod:`dress.apply`);
4. bind the dressed items to the target body at frame 0 (the region-aware
   plan of :mod:`dress.plan`) and re-evaluate the binding every frame (one
   sparse product, plus rigid parts and loose-part smoothing), with a
   temporally coherent penetration pass where needed
   (:class:`penetration_guard.PenetrationGuard`); with ``cloth`` the loose
   parts (skirts, dresses, coat tails, long hair) are simulated as cloth
   attached to their bound positions, the body as collider
   (:class:`cloth.ClothSolver`), and the penetration pass leaves them alone:
   it runs first, on the bound vertices, and the cloth's targets beside its
   pushes move with them (:class:`cloth.PushCarry`);
5. stream everything to one USD shot (:class:`usd_shot.ShotWriter`).

``mode="lbs"`` is the classic baseline instead: skin weights copied from the
body to the items (:mod:`skin_transfer`), items skinned per frame.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..dress import regions as R
from ..dress.apply import Placed, dress
from ..dress.apply import apply as apply_plan
from ..dress.hidden_body import SHOT_DEPTH, SHOT_MAX_GAP, hide_or_drop
from ..dress.item_weights import PIECE_WEIGHT, SKINNED_SUFFIX, rigid_pieces, skinned_items
from ..dress.plan import DressPlan
from ..dress.plan import plan as plan_dress
from ..dress.regions import vertex_regions
from ..dress.surface_layers import SurfaceLayers
from ..errors import NonFiniteError, USDInputError
from ..fit.body_fit import fit_character
from ..geometry.closest import SurfaceQuery
from ..geometry.mesh import edge_length_percentile, same_topology
from ..io.usd_carry import CarryPlan
from ..io.usd_shot import ShotWriter
from ..model import Character
from ..motion.clip_start import leading_rest_frames
from ..motion.floor import place_on_floor
from ..motion.retarget import BLOCK, retarget, retarget_stream
from ..motion.skinning import Skinner, skin_points, skinning_matrices
from ..progress import info, progress
from .cloth import ClothSolver, PushCarry
from .contact_hold import ContactHold
from .frame_eval import FrameEvaluator
from .hem_span import SLACK, HemSpan, narrow_frames
from .item_joints import HeldOut, JointFit, choose_items, extend_skeleton, plan_item_joints
from .loose import cloth_weights
from .measures import MEASURES, MotionMeasures, worst_frames
from .penetration_guard import PenetrationGuard
from .short_edges import ShortEdgeWeld
from .skin_fit import TRAINING_CLIPS, example_frames, fit_skinned_items
from .skin_transfer import transfer_weights
from .strain_limit import WELD_ROUND_PASSES, WELD_ROUNDS, StrainLimit


@dataclass
class AnimateOptions:
    k: int = 5
    start: int | None = 0             # first clip frame; None: "auto" (motion.clip_start.leading_rest_frames)
    end: int | None = None
    fps: float | None = 30.0          # None = the clip's native rate
    mode: str = "bind"                # "bind" or "lbs"
    mapping: dict | None = None       # user joint map {target: source}
    clip_frames: int | None = None    # value-clip chunk size (None = auto)
    velocities: bool = False
    write_skinned_items: bool = False  # old name of items="both" (kept for callers)
    items: str = "points"              # "points" (point caches), "skinned" (bound to the skeleton) or "both"
    penetration_margin: float = 0.001  # metres
    dress_pose: str = "auto"           # "first": dress in frame 0's pose; "bind": on the bind pose; "auto":
    #                                    bind on a coarse (low-poly) body, else first (dress_pose_for)
    measure_every: int = 0             # exact penetration statistics every N frames (0 = off)
    motion_measures: bool = True       # with measure_every: also the motion measures (animate.measures)
    untangle: bool = False             # dressing's untangle pass on frame 0 (see dress.apply.apply)
    floor: str = "auto"                # "auto": first frame on the rest floor; "keep" (motion.floor)
    pose_align: bool = True            # False: the dressing's body fit by similarity only (--no-pose)
    cloth: bool | None = None          # bind mode: loose parts as XPBD cloth (None: when the plan has any)
    strain_limit: bool = True          # bind mode: no item edge stretched beyond the body's own (strain_limit)
    contact_hold: bool = True          # bind mode: skirt parts held on the skin they touch (contact_hold)
    layer_hold: bool = True            # bind mode: outer layers kept over the items under them every frame
    #                                    (dress.surface_layers)
    max_frames: int | None = None      # refuse longer shots (retarget.OutputError)
    carry_plan: object = None          # io.usd_carry.CarryPlan: the inputs' materials, primvars... to keep
    rigid_items: str = "skinned"       # bind mode: "skinned" (shoes, hats, glasses by LBS with their binding's
    #                                    weights, _RigidItems) or "bound" (binding, rigid fit, penetration guard)
    hidden_body: str = "none"          # "subset": name the covered body faces; "delete": drop them (hidden_body)
    skin_fit: bool = True              # bind mode, items skinned|both: the skinned copies' rest points fitted to
    #                                    example poses (skin_fit)
    item_joints: bool = True           # bind mode with cloth, items skinned|both: the copies' loose parts on
    #                                    joints of their own, animated from the cloth (item_joints)
    compare_item_joints: bool = False  # also measure the copies on joints with the skin's weights instead (rows
    #                                    "<item>_skinned_without_joints"; the benchmarks' baseline in the same shot)
    frame_sink: object = None          # skin_fit.FrameRecorder: gets every frame's matrices, body and items
    skin_examples: tuple | None = None  # skin_fit.training_frames of this reference and target, made once for
    #                                     several clips (None: made here when skin_fit needs them)


@dataclass
class AnimateReport:
    frames: int = 0
    fps: float = 0.0
    timings: dict = field(default_factory=dict)
    per_frame_penetration: list = field(default_factory=list)  # fraction of item vertices
    worst_frame_penetration: float = 0.0
    mapping: dict = field(default_factory=dict)
    # motion measures (animate.measures), against the items dressed statically
    # on the target's bind pose; per measured frame and their worst frames
    measured_frames: list = field(default_factory=list)
    motion_series: dict = field(default_factory=dict)   # {item: {measure: [value per measured frame]}}
    motion_worst: dict = field(default_factory=dict)    # {item: {measure: {"value", "frame"}}}
    cloth_vertices: int = 0  # item vertices simulated as cloth
    skinned_items: list = field(default_factory=list)  # names of the items written bound to the skeleton
    skinned_rigid_items: list = field(default_factory=list)  # rigid items and skin decals skinned (bind mode)
    skin_fit: dict = field(default_factory=dict)  # the skinned copies' fit (skin_fit): frames, moved mm
    item_joints: dict = field(default_factory=dict)  # {item: joints of its own} in the skinned output
    dress_pose: str = ""  # the pose frame 0 was dressed in: "first" or "bind" (AnimateOptions.dress_pose resolved)
    strain_limited_edges: int = 0  # item edges the strain limit shortened, summed over the frames (-1: off)
    # skirts whose hem cannot go round the legs at its height in some frames
    # (animate.hem_span): {item: {"hem_m", "outline_max_m", "frames", "first", "last", "worst", "hem_height_m"}}
    narrow_hems: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"frames": self.frames, "fps": self.fps, "timings_s": self.timings,
                "worst_frame_new_penetration_pct": 100 * self.worst_frame_penetration,
                "per_frame_new_penetration_pct": [round(100 * x, 4) for x in self.per_frame_penetration],
                "motion_worst": self.motion_worst, "measured_frames": self.measured_frames,
                "motion_per_frame": self.motion_series,
                "cloth_vertices": self.cloth_vertices, "skinned_items": self.skinned_items,
                "skinned_rigid_items": self.skinned_rigid_items, "dress_pose": self.dress_pose,
                "strain_limited_edges": self.strain_limited_edges, "narrow_hems": self.narrow_hems,
                "skin_fit": self.skin_fit, "item_joints": self.item_joints, "mapping": self.mapping}


#: a target body whose edges (99th percentile) are this many times the
#: reference body's is coarse (a low-poly game body): dressed on its bind pose
COARSE_EDGE_RATIO = 2.0

#: the penetration pass gives a pushed vertex back at most this clearance
#: (PenetrationGuard's max_clearance): it keeps items out of the body, the
#: binding keeps their volume. Every-clip sweep, worst over 8 clips x 3 dev
#: references, against no cap / 10 mm / 3 mm: female_casualsuit02 stretch
#: p99 6.06 / 3.98 / 3.06 and new penetrations 6.32 / 2.98 / 2.80 %;
#: male_casualsuit01 1.84 / 1.75 / 1.57 and 1.79 / 1.45 / 1.34 %; 2 mm was
#: better still on the jump (2.39, 1.67 %) but leaves a coarse item's
#: triangles 1 mm over the margin for the body to sag through
GUARD_MAX_CLEARANCE = 0.003

#: Jacobi passes of the strain limit on the dress of a shot's first pose
#: (:func:`relax_first_dress`; 0: none). Every-clip sweep (8 CMU clips x 3
#: dev references), same tree otherwise, 0 -> 64 passes: the means over the
#: clips of the shots' mean stretch max beyond the body's: ponytail01 1.62
#: -> 1.49, female_casualsuit02 2.19 -> 1.95, male_casualsuit01 1.82 ->
#: 1.62, the long skirt 1.30 -> 1.25; the worst of all clips'
#: female_casualsuit02 6.32 -> 4.37, ponytail01 p99 1.49 -> 1.28; the long
#: skirt's new penetrations 0.47 -> 0.57 % (mean), 4.49 -> 4.91 % (worst)
FIRST_DRESS_PASSES = 64


def dress_pose_for(reference: Character, target: Character, dress_pose: str = "auto",
                   coarse: bool | None = None) -> str:
    """The pose a shot's frame 0 is dressed in: ``dress_pose`` itself unless
    it is ``"auto"``; then ``"bind"`` (the items dressed on the target's
    bind pose, as ``wearfit dress`` dresses them, and carried to frame 0 by
    the binding) when the target's body is coarse: of another topology than
    the reference's, its edges' 99th percentile over ``COARSE_EDGE_RATIO``
    times the reference body's; else ``"first"`` (the clip's first pose: the
    reference posed through its own rig, its items with it, fitted onto the
    posed target).

    A low-poly body posed by its skin has faceted joints and rigid pieces
    that slide over each other; fitted onto it in the clip's pose, the dense
    reference body takes them on and the items with it. On GDQuest's
    mannequin (edges p99 93 mm against ref_female's 39; ref_female, CMU
    walk) the posed fit bulged the nape through 486 of the ponytail's 3,718
    vertices (57 on the bind pose) and the penetration pass threw them up
    to 18 cm: the worst frame's stretch p99 12.6 -> 3.6 dressed on the bind
    pose, coverage loss 31 -> 3.7 %, the suit's stretch p99 2.36 -> 1.48.
    A dense target of another topology (a remeshed body) dresses better in
    the clip's pose: the demo's arm raise on its remeshed sample, worst
    frame's new penetrations 0.65 % against 3.5 % on the bind pose.
    ``coarse``: :func:`coarse_body` of the two, if the caller has it."""
    if dress_pose != "auto":
        return dress_pose
    return "bind" if (coarse_body(reference, target) if coarse is None else coarse) else "first"


def coarse_body(reference: Character, target: Character) -> bool:
    """True when the target's body is coarse (a low-poly game body): of
    another topology than the reference's, its edges' 99th percentile over
    ``COARSE_EDGE_RATIO`` times the reference body's."""
    tb, rb = target.body, reference.body
    if same_topology(tb.points, tb.faces, rb.points, rb.faces):
        return False
    return edge_length_percentile(tb.points, tb.faces) > COARSE_EDGE_RATIO * edge_length_percentile(rb.points, rb.faces)


def _posed_skeleton(skeleton, world0):
    """The skeleton re-bound at the pose ``world0`` (J, 4, 4)."""
    return replace(skeleton, bind_world=np.asarray(world0, dtype=np.float64))


def animate(reference: Character, target: Character, motion, out_path, options: AnimateOptions | None = None,
            ref_plan: DressPlan | None = None) -> AnimateReport:
    """Dress ``target`` with ``reference``'s items, animate it with ``motion``
    (a :class:`bvh.BVHMotion`) and write the shot to ``out_path``.
    ``ref_plan``: the reference's dressing plan (:func:`dress.plan.plan` with
    ``k=options.k``) built earlier, reused instead of a new one (it is left
    unchanged, so one plan serves every clip and target)."""
    opt = options or AnimateOptions()
    for name, value, allowed in (("mode", opt.mode, ("bind", "lbs")),
                                 ("rigid_items", opt.rigid_items, ("skinned", "bound")),
                                 ("items", opt.items, ("points", "skinned", "both")),
                                 ("dress_pose", opt.dress_pose, ("auto", "first", "bind"))):
        if value not in allowed:
            raise ValueError(f"AnimateOptions.{name}: expected one of {', '.join(allowed)}, got {value!r}")
    rep = AnimateReport()
    t_all = time.perf_counter()
    if target.skeleton is None:
        raise USDInputError(target.source, "the target has no skeleton: cannot animate it")
    if reference.skeleton is None:
        raise USDInputError(reference.source, "the reference has no skeleton")
    if not reference.items:
        raise USDInputError(reference.source, "the reference holds no wearable items (no Mesh besides the body)")
    coarse = coarse_body(reference, target)
    pose = dress_pose_for(reference, target, opt.dress_pose, coarse=coarse)
    if pose != opt.dress_pose:
        opt = replace(opt, dress_pose=pose)
        if pose == "bind" and opt.mode == "bind":
            info(f"{target.source}: a coarse body (low-poly: edges over {COARSE_EDGE_RATIO:g} times the "
                 f"reference's): dressed on its bind pose as `wearfit dress` dresses it, frame 0 reached through "
                 f"the binding (--dress-pose first dresses the clip's first pose)")
    rep.dress_pose = pose

    # 1. retarget ------------------------------------------------------------
    t0 = time.perf_counter()
    # frames computed a block at a time in the frame loop (memory flat in the
    # shot's length); the block's SkelAnimation samples are written with it
    start = opt.start
    if start is None:
        start = leading_rest_frames(motion)
        if start:
            what = "frame 0 is" if start == 1 else f"frames 0-{start - 1} blend from"
            info(f"{motion.path}: {what} the converter's rest pose (a T-pose): the shot starts at clip frame "
                 f"{start} (--start 0 keeps it)")
    rt = retarget_stream(motion, target.skeleton, mapping=opt.mapping, start=start, end=opt.end,
                         fps=opt.fps, max_frames=opt.max_frames)
    rt, _ = place_on_floor(rt, target.skeleton, target.body, opt.floor)
    world = _FrameWorlds(rt)
    n_frames = rt.n_frames
    rep.frames, rep.fps = n_frames, float(rt.fps)
    rep.mapping = rt.report
    rep.timings["retarget"] = time.perf_counter() - t0
    info(f"retargeted {motion.path}: {n_frames} frames at {rt.fps:g} fps")

    body = target.body
    def skin_mats(f):
        return skinning_matrices(target.skeleton.bind_world, world(f))  # (J, 4, 4)

    # 2./3. dress -------------------------------------------------------------
    t0 = time.perf_counter()
    body_skinner = Skinner(body.points, body.joint_indices, body.joint_weights, target.skeleton.n_joints)
    body0 = body_skinner(skin_mats(0))
    # one plan, on the reference in its rest pose: regions and bound triangles
    # are best found with the limbs apart (a posed body, hands hanging beside
    # a skirt, would hand skirt parts to the arms); the posed dressing rebinds it
    if ref_plan is None:
        ref_plan = plan_dress(reference, k=opt.k)
    whole = _skinned_whole(ref_plan, opt, coarse)
    bind_dressed = skin_src = rigid = None
    if opt.mode == "lbs" or opt.dress_pose == "bind":
        # dressed on the target's bind pose; frame 0 comes from the binding
        dressed = dress_items(reference, target, k=opt.k, untangle=opt.untangle, prepared=ref_plan,
                              pose_align=opt.pose_align)
        base_body, base_skeleton = body.points, target.skeleton
    else:
        # dressed in frame 0's pose: the reference is posed through its own
        # rig, its items follow it, it is fitted onto the posed target
        ref_rt = retarget(motion, reference.skeleton, mapping=opt.mapping, start=start,
                          end=start + 1, fps=None)
        ref_world0 = ref_rt.world[0]
        ref_body0 = skin_points(reference.body.points, reference.body.joint_indices,
                                reference.body.joint_weights,
                                skinning_matrices(reference.skeleton.bind_world, ref_world0))
        posed_pts, _, _, _ = apply_plan(ref_plan, ref_body0, reference.body.faces, penetration=False)
        # the posed items bound where they are, with the rest pose's triangles
        posed_plan = ref_plan.rebound(ref_body0, posed_pts)
        posed_ref = replace(reference, body=reference.body.copy_with_points(ref_body0),
                            skeleton=_posed_skeleton(reference.skeleton, ref_world0), items=posed_plan.items)
        base_skeleton = _posed_skeleton(target.skeleton, world(0))
        posed_target = replace(target, body=target.body.copy_with_points(body0), skeleton=base_skeleton)
        placed = None
        if whole:
            # the skinned rigid items where the shot's frame 0 puts them: the
            # items over them are dressed against those. Placed by the plan's
            # similarity fit of the posed skin, a shoe's collar stood 38 mm off
            # the shin in the CMU run's first pose (2.2 mm skinned) and the
            # trouser hem over it was lifted round the leg (male_casualsuit01,
            # its ring 1.6x its length from frame 0 on)
            bind_dressed = _bind_dress(reference, target, None, opt, ref_plan)
            skin_src = skinned_items(bind_dressed, target)
            rigid = _RigidItems.of_plan(skin_src, whole, ref_plan, target.skeleton.n_joints)
            placed = Placed(rigid.rows, rigid.skinner(skin_mats(0)))
        dressed = dress_items(posed_ref, posed_target, k=opt.k, untangle=opt.untangle, prepared=posed_plan,
                              pose_align=opt.pose_align, placed=placed)
        base_body = body0
    items_base, dress_timings = dressed.items, dressed.timings
    if opt.mode == "bind" and opt.strain_limit and opt.dress_pose != "bind" and FIRST_DRESS_PASSES:
        # the first pose's dress strain-limited against the bind pose's
        # before anything is bound to it (see FIRST_DRESS_PASSES)
        if bind_dressed is None:
            bind_dressed = _bind_dress(reference, target, dressed, opt, ref_plan)
        items_base = relax_first_dress(items_base, bind_dressed.items, dressed.plan.rigid_mask(),
                                       dressed.plan.mesh.edges, body.faces, body.points, base_body)
    rep.timings["dress"] = time.perf_counter() - t0
    rep.timings["dress_detail"] = dress_timings

    # 4. per-frame evaluation ---------------------------------------------------
    t0 = time.perf_counter()
    items = list(items_base)
    sizes = [m.n_points for m in items]
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    all_base = np.concatenate([m.points for m in items])
    if opt.mode == "lbs":
        ji, jw = transfer_weights(body.points, body.faces, body.joint_indices, body.joint_weights,
                                  all_base, target.skeleton.n_joints)
        evaluator = _LBSEvaluator(all_base, ji, jw, skin_mats, target.skeleton.n_joints)
        items_for_skin = [replace(m, joint_indices=ji[offsets[i]:offsets[i + 1]],
                                  joint_weights=jw[offsets[i]:offsets[i + 1]])
                          for i, m in enumerate(items)]
    else:
        # the dressed items bound to the target with the same region-aware
        # plan as dressing (skirts from the hips, rigid parts, loose parts
        # smoothed): a linear evaluation per frame
        if np.array_equal(body.faces, reference.body.faces):
            # same body topology (the fitting's fast path): the dressing's plan,
            # rebound to the dressed items on the target's frame 0
            frame_plan = dressed.plan.rebound(base_body, all_base)
        else:
            base = replace(target, body=body.copy_with_points(base_body), skeleton=base_skeleton, items=items)
            # parts the dressing released on this body stay free (bound, not rigid)
            released = [n for n in ref_plan.rigid_items if n not in dressed.plan.rigid_items]
            frame_plan = plan_dress(base, k=opt.k, regions=ref_plan.regions, free_items=released)
        frame_eval = FrameEvaluator(frame_plan)
        evaluator = lambda f, body_f: frame_eval(body_f)  # noqa: E731
        items_for_skin = []
    cloth = None
    if opt.mode == "bind" and opt.cloth is not False:
        # the edges keep their static-dress lengths; the cloth is dressed into
        # frame 0 by simulation from the target's bind pose
        cloth = ClothSolver(frame_plan, body.faces, body0, all_base)
        if cloth.active:
            # the hanging parts rest as dressed on the bind pose (the relaxed
            # cut the measures judge against: a first frame with a leg
            # forward dresses a skirt stretched round it, a nodding head the
            # hair stretched down the back)
            if len(cloth.hanging):
                if bind_dressed is None:
                    bind_dressed = _bind_dress(reference, target, dressed, opt, ref_plan)
                cloth.set_rest(np.concatenate([m.points for m in bind_dressed.items]))
            cloth_pts0 = cloth.preroll(body.points, body0, lambda b: evaluator(0, b), 1.0 / rt.fps)
        else:
            cloth = None
    items_mode = "both" if (opt.write_skinned_items and opt.items == "points") else opt.items
    # the items skinned to the target's skeleton, once: in lbs mode with the
    # shot's own weights, else dressed on the bind pose with the weights of
    # their binding (dress.item_weights.skinned_items, as `wearfit dress
    # --items` writes them); for the skinned rigid items and the skinned copies
    if skin_src is None:
        skin_src = items_for_skin
        if opt.mode == "bind" and (whole or items_mode != "points"):
            if bind_dressed is None:
                bind_dressed = _bind_dress(reference, target, dressed, opt, ref_plan)
            skin_src = skinned_items(bind_dressed, target)
    # rigid items (shoes, hats, glasses) skinned to the skeleton (see _RigidItems)
    if whole and rigid is None:
        rigid = _RigidItems.of_plan(skin_src, whole, ref_plan, target.skeleton.n_joints)
    if rigid is not None:
        rep.skinned_rigid_items = rigid.names
    rep.timings["bind"] = time.perf_counter() - t0
    # clearances to keep (and "new penetration" = inside now, outside when dressed)
    pushed_rows = guard = push_guard = None
    # the items at frame 0 as written: the skinned rigid items where skinning puts them
    frame0_items = all_base
    if rigid is not None:
        frame0_items = all_base.copy()
        frame0_items[rigid.rows] = rigid.skinner(skin_mats(0))
    # the items dressed on the bind pose, point for point with the shot's
    # (None where they differ): the strain limit's rest and the guard's
    # outside test (the garment at rest on this body; the frame-0 dress of a
    # posed first frame is stretched already, and can lie in the skin)
    if opt.mode == "bind" and opt.strain_limit and bind_dressed is None:
        bind_dressed = _bind_dress(reference, target, dressed, opt, ref_plan)
    bind_rest = None
    if bind_dressed is not None:
        bind_rest = np.concatenate([m.points for m in bind_dressed.items])
        if bind_rest.shape != all_base.shape:
            bind_rest = None
    # vertices joined by sub-millimetre edges in the items as authored move as one (short_edges)
    weld = None
    if opt.mode == "bind":
        authored = ref_plan.ref_points if len(ref_plan.ref_points) == len(all_base) else all_base
        weld = ShortEdgeWeld(authored, frame_plan.mesh.edges)
    # no edge stretched beyond the body's own stretch under it (strain_limit)
    strain = None
    if opt.mode == "bind" and opt.strain_limit:
        # not the items skinned whole (shoes, hats, eyebrows) but their
        # hinges' vertices (a shoe's between the sole and the toe cap or the
        # collar: in no rigid piece); a rigid patch of a garment is moved by
        # the guard vertex by vertex and may tear like the rest
        movable = np.ones(len(all_base), dtype=bool)
        if rigid is not None:
            movable[rigid.rows] = False
            movable[rigid.hinge_rows] = True
        # its rest: the first pose's dress, or the bind pose's; the weld inside its every pass
        rest_body, rest_items = (base_body, all_base) if bind_rest is None else (target.body.points, bind_rest)
        strain = StrainLimit(rest_items, frame_plan.mesh.edges, body.faces, rest_body, movable, weld=weld)
    # outer layers kept over the items under them, surface against surface (dress.surface_layers)
    layer_hold = None
    if opt.mode == "bind" and opt.layer_hold and frame_plan.layers:
        # not the rigid groups' vertices (a suit's belt moves as a whole), nor
        # the items skinned whole but their hinges
        movable = ~frame_plan.rigid_mask()
        if rigid is not None:
            movable[rigid.rows] = False
            movable[rigid.hinge_rows] = True
        layer_hold = SurfaceLayers(frame_plan.layers, frame_plan.offsets, frame_plan.mesh.faces, body.faces,
                                   base_body, frame0_items, movable=movable,
                                   rigid_inner=frame_plan.rigid_item_rows())
        layer_hold = layer_hold if layer_hold.active else None
    # vertices outside the body in the bind pose's dress are guarded even
    # where the first pose's dress starts them inside it (the strain limit's
    # rest clearances are theirs)
    also = None
    if opt.mode == "bind" and bind_rest is not None:
        clear = (strain.clearance0 if strain is not None
                 else SurfaceQuery(body.faces, body.points).signed_distance(bind_rest))
        also = clear > 0.0
    if cloth is None or opt.measure_every:
        # it pushes (and spreads its pushes over the items) in bind mode when
        # no other guard does; else it only counts penetrations
        pushes = opt.mode == "bind" and cloth is None and rigid is None
        guard = PenetrationGuard(body.faces, base_body, frame0_items, margin=opt.penetration_margin,
                                 item_neighbours=frame_plan.mesh.neighbours if pushes else None,
                                 max_clearance=GUARD_MAX_CLEARANCE, also=also if pushes else None)
    if cloth is not None or rigid is not None:
        # the cloth keeps its own distance from the body: the guard would pull
        # it back to its frame-0 clearance; "new penetration" still counts it.
        # Skinned rigid items are left as skinning puts them (a shoe bends)
        keep = np.ones(len(all_base), dtype=bool)
        if cloth is not None:
            keep &= cloth.weights <= 0
            rep.cloth_vertices = cloth.n_free
        if rigid is not None:
            # but their hinges' vertices (a shoe's collar, its toe band),
            # which sank up to 8 mm into the ankle (shoes01, arms held high)
            keep[rigid.rows] = False
            keep[rigid.hinge_rows] = True
        pushed_rows = np.flatnonzero(keep)
        nb = frame_plan.mesh.neighbours.tocsr()
        push_guard = PenetrationGuard(body.faces, base_body, all_base[pushed_rows], margin=opt.penetration_margin,
                                      item_neighbours=nb[pushed_rows][:, pushed_rows],
                                      max_clearance=GUARD_MAX_CLEARANCE,
                                      also=None if also is None else also[pushed_rows])
        if cloth is not None:
            carry = PushCarry(nb, pushed_rows, cloth.weights)
    # skirt parts held on the skin they touch in the static dress (their binding's
    # frames sit above the buttocks; contact_hold): the bound rows, not the
    # cloth's, nor rigid items'
    hold = None
    if opt.mode == "bind" and opt.contact_hold:
        skirt = ref_plan.skirt_mask(parts=True)
        if cloth is not None:
            skirt &= cloth.weights <= 0
        if rigid is not None:
            skirt[rigid.rows] = False
        if skirt.any():
            # the contact of the static dress (the bind pose's, as the
            # measures judge it; a first pose's dress can stand off already)
            rest_body, rest_items = (base_body, frame0_items) if bind_rest is None else (target.body.points, bind_rest)
            hold = ContactHold(body.faces, rest_body, rest_items, np.flatnonzero(skirt),
                               neighbours=frame_plan.mesh.neighbours)
            hold = hold if hold.active else None
    # the skirts' free vertices kept by the strain limit off the skin under
    # them as the cloth left them (hair gained no cover from it, only stretch)
    floor_rows = ref_plan.skirt_mask() if cloth is not None and strain is not None else None
    if floor_rows is not None and not floor_rows.any():
        floor_rows = None
    measures = None
    if opt.measure_every and opt.motion_measures:
        t0 = time.perf_counter()
        if bind_dressed is None:
            bind_dressed = _bind_dress(reference, target, dressed, opt, ref_plan)
        measures = _motion_measures(target, bind_dressed, ref_plan)
        rep.timings["measure_setup"] = time.perf_counter() - t0

    hems = _hem_spans(target, ref_plan, bind_dressed.items if bind_dressed is not None else items,
                      target.body.points if bind_dressed is not None else base_body)
    hem_outlines = {name: np.zeros(n_frames) for name in hems}

    skinned = None
    if items_mode != "points":
        copies = skin_src
        t0 = time.perf_counter()
        frames = None
        if opt.mode == "bind" and opt.skin_fit:
            frames = opt.skin_examples if opt.skin_examples is not None else example_frames(reference, target,
                                                                                            ref_plan, opt)
        if frames is not None:
            # rest points that the skeleton's skinning carries onto the redress of example poses
            copies, moved = fit_skinned_items(skin_src, body.faces, target.body.points, frames)
            rep.skin_fit = {"frames": int(len(frames[0])), "clips": list(TRAINING_CLIPS),
                            "vertices": int((~frames[3]).sum()),
                            "moved_p95_mm": float(1000 * np.percentile(moved[~frames[3]], 95)) if (~frames[3]).any()
                            else 0.0, "moved_max_mm": float(1000 * moved.max())}
            rep.timings["skin_fit"] = time.perf_counter() - t0
            info(f"skinned copies fitted to {rep.skin_fit['frames']} example poses ({', '.join(TRAINING_CLIPS)}): "
                 f"rest points moved p95 {rep.skin_fit['moved_p95_mm']:.1f} mm, max "
                 f"{rep.skin_fit['moved_max_mm']:.1f} mm ({rep.timings['skin_fit']:.1f} s; --no-skin-fit skips)")
        skinned = _skinned_copies(copies, SKINNED_SUFFIX if items_mode == "both" else "")
        rep.skinned_items = [m.name for m in skinned]
    # the copies' loose parts on joints of their own, driven by the cloth (item_joints)
    item_joints = joint_fit = None
    plain_copies = skinned   # the copies with the skin's weights (compare_item_joints)
    if skinned is not None and cloth is not None and opt.item_joints and [m.n_points for m in skinned] == sizes:
        item_joints, skinned, joint_fit, frames = _item_joints(reference, target, skinned, frames, frame_plan,
                                                               ref_plan, cloth, opt, rep)
    n_skin_joints = target.skeleton.n_joints + (0 if item_joints is None else item_joints.n_joints)
    written_items = items if items_mode != "skinned" else []

    # the skinned copies measured as UsdSkel poses them (our LBS equals it),
    # against the same static dress: their figures go in the report as
    # "<item>_skinned" beside the point caches'
    skin_copies = plain_measure = None
    if skinned is not None and measures is not None:
        skin_copies = _SkinnedCopies(skinned, n_skin_joints, measures.names)
        if opt.compare_item_joints and item_joints is not None:
            plain_measure = (_SkinnedCopies(plain_copies, target.skeleton.n_joints, measures.names),
                             {n.removesuffix(SKINNED_SUFFIX) for n in item_joints.items})
    clip_frames = opt.clip_frames
    if clip_frames is None and n_frames > 2000:
        clip_frames = 500
    t_lbs = t_eval = t_pen = t_write = t_measure = t_joints = 0.0
    written, carry_plan = _hidden_body(target, base_body, items, opt)
    with ShotWriter(out_path, written, written_items, fps=rt.fps, n_frames=n_frames, clip_frames=clip_frames,
                    velocities=opt.velocities, carry_plan=carry_plan, skinned_items=skinned,
                    skeleton=None if item_joints is None else extend_skeleton(written.skeleton, item_joints)) as w:
        def write_block(a, block):
            nonlocal t_write
            tw = time.perf_counter()
            w.write_animation(rt.local(world=block), first_frame=a)
            t_write += time.perf_counter() - tw
        world.on_block = write_block
        world.reset()
        world(0)  # frame 0's block (and animation samples) even where frame 0 skips the skinning
        if opt.frame_sink is not None:
            # the vertices the binding does not move: the cloth's, the items skinned whole
            free = np.zeros(len(all_base), dtype=bool)
            if cloth is not None:
                free |= cloth.weights > 0
            if rigid is not None:
                # their rigid pieces; a hinge's vertices (a shoe's toe band, short
                # hair's nape), pushed out by the guard here, are fitted
                free[rigid.rows] = True
                free[rigid.hinge_rows] = False
            opt.frame_sink.start(free)
        for f in progress(range(n_frames), total=n_frames, desc="animate", unit="frame"):
            ta = time.perf_counter()
            mats = skin_mats(f)
            body_f = body0 if f == 0 else body_skinner(mats)
            tb = time.perf_counter()
            pts = evaluator(f, body_f)
            if rigid is not None:
                # before the guard, which pushes their hinges' vertices
                rigid_pts = rigid.skinner(mats)
                pts[rigid.rows] = rigid_pts
            guarded = False
            if cloth is not None and f > 0:
                # the bound vertices pushed out first, the cloth's targets
                # beside them carried along: the cloth hangs from where the
                # guard puts them (pushed after it, a bound vertex stood out
                # of its cloth neighbours)
                tc = time.perf_counter()
                evaluated = pts[pushed_rows]
                if hold is not None:
                    pts = hold(body_f, pts)
                moved = push_guard.apply(body_f, pts[pushed_rows])[0]
                if len(carry):
                    pts[carry.rows] += carry(moved - evaluated)
                pts[pushed_rows] = moved
                t_pen += time.perf_counter() - tc
                guarded = True
                pts = cloth.step(body_f, pts, 1.0 / rt.fps)
            elif cloth is not None:
                pts = cloth_pts0
                if rigid is not None:
                    pts[rigid.rows] = rigid_pts
            tc = time.perf_counter()
            if hold is not None and not guarded:
                pts = hold(body_f, pts)
            if opt.mode == "bind" and pushed_rows is not None and not guarded:
                pts[pushed_rows] = push_guard.apply(body_f, pts[pushed_rows])[0]
            elif opt.mode == "bind" and not guarded:
                pts, _ = guard.apply(body_f, pts)
            if layer_hold is not None:
                pts = layer_hold(body_f, pts)
            floors = cloth.floors(rows=floor_rows) if floor_rows is not None else None
            if strain is not None:
                if pushed_rows is not None:
                    pushed = np.zeros(len(pts), dtype=bool)
                    pushed[pushed_rows] = push_guard.push > 0
                else:
                    pushed = guard.push > 0
                if layer_hold is not None:
                    pushed |= layer_hold.pushed
                strain(body_f, pts, pushed, planes=floors)
            if weld is not None:
                weld(pts)
                if strain is not None and WELD_ROUND_PASSES:
                    # the weld re-stretches its groups' other edges: more, shorter rounds
                    for _ in range(WELD_ROUNDS):
                        strain(body_f, pts, pushed, iterations=WELD_ROUND_PASSES, planes=floors)
                        weld(pts)
            check_finite_points(pts, f, rt, motion.path)
            skin_mats_f, tj = mats, 0.0
            if joint_fit is not None:
                tj = time.perf_counter()
                deltas = joint_fit(pts, mats, body_f)
                w.write_item_joints(f, item_joints.world(deltas))
                skin_mats_f = np.concatenate([mats, deltas])
                tj = time.perf_counter() - tj
                t_joints += tj
            if opt.frame_sink is not None:
                opt.frame_sink.add(f, mats, body_f, pts)
            td = time.perf_counter()
            t_pen += td - tc - tj
            if hems:   # the legs' outline at each skirt's hem (a measure: its time counted as one)
                for name, span in hems.items():
                    hem_outlines[name][f] = span(body_f)
                tm = time.perf_counter()
                t_measure += tm - td
                td = tm
            if opt.measure_every and (f % opt.measure_every == 0 or f == n_frames - 1):
                rep.per_frame_penetration.append(guard.inside_fraction(body_f, pts))
                if measures is not None:
                    _record(rep, f, measures(body_f, pts))
                    if skin_copies is not None:
                        _record(rep, None, skin_copies.rows(measures, body_f, skin_mats_f))
                    if plain_measure is not None:
                        copies_f, on_joints = plain_measure
                        rows = [r for r in copies_f.rows(measures, body_f, mats)
                                if r["item"].removesuffix(SKINNED_SUFFIX) in on_joints]
                        for r in rows:
                            r["item"] += "_without_joints"
                        _record(rep, None, rows)
                tm = time.perf_counter()
                t_measure += tm - td
                td = tm
            w.write_frame(f, [pts[offsets[i]:offsets[i + 1]] for i in range(len(written_items))])
            te = time.perf_counter()
            t_lbs += tb - ta
            t_eval += tc - tb
            t_write += te - td
        tw = time.perf_counter()
    t_write += time.perf_counter() - tw
    rep.worst_frame_penetration = max(rep.per_frame_penetration) if rep.per_frame_penetration else 0.0
    rep.strain_limited_edges = strain.stats["edges_limited"] if strain is not None else -1
    _report_narrow_hems(rep, hems, hem_outlines, rt)
    if measures is not None:
        rep.motion_worst = worst_frames(rep.motion_series, rep.measured_frames)
    rep.timings.update({"lbs_total": t_lbs, "evaluate_total": t_eval, "penetration_total": t_pen,
                        "write_total": t_write, "measure_total": t_measure, "item_joints_total": t_joints,
                        "cloth_total": cloth.timings["solve_s"] if cloth is not None else 0.0,
                        "cloth_cpu_total": cloth.timings["solve_cpu_s"] if cloth is not None else 0.0,
                        "lbs_fps": n_frames / max(t_lbs, 1e-9),
                        "evaluate_fps": n_frames / max(t_eval, 1e-9),
                        "write_fps": n_frames / max(t_write, 1e-9),
                        "total": time.perf_counter() - t_all})
    return rep


def _hidden_body(target: Character, base_body, items, opt: AnimateOptions):
    """The target to write (its body without the hidden faces with
    ``hidden_body="delete"``) and the carry plan with the hidden subsets:
    faces covered at frame 0 and deep enough under the items to stay covered
    in motion (dress.hidden_body.SHOT_DEPTH / SHOT_MAX_GAP)."""
    if opt.hidden_body == "none":
        return target, opt.carry_plan
    body, subsets, keep = hide_or_drop(target.body, base_body, [(m.name, m.points, m.faces) for m in items],
                                       delete=opt.hidden_body == "delete", depth=SHOT_DEPTH, max_gap=SHOT_MAX_GAP)
    plan = opt.carry_plan if opt.carry_plan is not None else CarryPlan()
    info(f"hidden body: {len(subsets.get('hidden_under_items', [])) if keep is None else int((~keep).sum())} "
         f"faces {'deleted' if keep is not None else 'named hidden_under_items'}")
    return replace(target, body=body), plan.with_hidden(subsets, keep)


def _item_joints(reference, target, skinned: list, frames, frame_plan, ref_plan: DressPlan, cloth: ClothSolver,
                 opt: AnimateOptions, rep: AnimateReport) -> tuple:
    """The skinned copies' joints of their own (:mod:`item_joints`): (the
    :class:`item_joints.ItemJoints` or None, the copies with their weights,
    the per-frame :class:`item_joints.JointFit` or None, the example frames
    (made here when the skinned-copy fit did not make them))."""
    t0 = time.perf_counter()
    blend = _joint_blend(frame_plan, ref_plan, cloth)
    if not blend.any():
        return None, skinned, None, frames
    if frames is None:
        frames = opt.skin_examples if opt.skin_examples is not None else example_frames(reference, target,
                                                                                        ref_plan, opt)
        if frames is None:
            return None, skinned, None, frames
    skirt = ref_plan.skirt_mask()
    skirts = {m.name for m, sl in zip(skinned, ref_plan.item_slices()) if skirt[sl].any()}
    plan = plan_item_joints(skinned, blend, target.skeleton, skirts=skirts)
    chosen_blend, chosen = choose_items(skinned, blend, target.skeleton, frames, target.body.faces,
                                        target.body.points, skirts=skirts, plan=plan)
    for name, c in chosen.items():
        info(f"{name}: {'on' if c['on'] else 'not on'} joints of its own (over the example poses its loose part "
             f"lies {c['gap_skin_mm']:.1f} mm from the cloth at the 95th percentile with the skin's weights, "
             f"{c['gap_joints_mm']:.1f} mm with its own joints; worst new penetrations {c['new_pen_skin_pct']:.2f} / "
             f"{c['new_pen_joints_pct']:.2f} %, the cloth's {c['new_pen_redress_pct']:.2f} %)")
    # planned again only when the choice left an item out
    joints, skinned = (plan if np.array_equal(chosen_blend, blend) else
                       plan_item_joints(skinned, chosen_blend, target.skeleton, skirts=skirts))
    rep.timings["item_joints"] = time.perf_counter() - t0
    if joints is None:
        return None, skinned, None, frames
    fit = JointFit(np.concatenate([m.points for m in skinned]), np.concatenate([m.joint_indices for m in skinned]),
                   np.concatenate([m.joint_weights for m in skinned]), joints,
                   held_out=HeldOut(target.body.faces, target.body.points))
    rep.item_joints = {n: joints.items.count(n) for n in dict.fromkeys(joints.items)}
    info("skinned copies: loose parts on joints of their own, animated from the cloth ("
         + ", ".join(f"{n} {k}" for n, k in rep.item_joints.items()) + f"; {rep.timings['item_joints']:.1f} s; "
         "--no-item-joints keeps the skin's weights)")
    return joints, skinned, fit, frames


def _joint_blend(frame_plan, ref_plan: DressPlan, cloth: ClothSolver) -> np.ndarray:
    """(M,) the share of the item joints in the skinned copies' weights
    (:func:`item_joints.plan_item_joints`): the cloth weight of the items the
    cloth simulates, with their loose pieces that no edge joins to the
    attachment hanging too (a ponytail's strands: bound to the head and the
    back by the cloth weight, they went 3-7 cm into the back when the head
    tipped back in the arms-held-high dance). Not from the attachment line
    on (``hang_start`` 0): the ponytail's scalp cap, blended onto joints
    fitted to the tail, opened over the skull. Skirts too, with more joints
    (``item_joints.SKIRT_VERTICES_PER_JOINT``) fitted to the cloth held out
    from the legs (``item_joints.HeldOut``); with the ponytail's 24 joints
    fitted to the cloth itself ``ref_female_longskirt``'s skirt went 1.1 ->
    13 % into the legs in the CMU run on ``body_female_heavy``."""
    blend = cloth_weights(frame_plan, detached=True)
    for sl in frame_plan.item_slices():
        if not np.any(cloth.weights[sl] > 0):
            blend[sl] = 0.0
    return blend


def _skinned_copies(skinned: list, suffix: str) -> list:
    """The items as meshes bound to the target's skeleton, in its bind pose
    (the shot's SkelAnimation poses them through UsdSkel): copies of
    ``skinned`` (meshes with joint indices and weights) with ``suffix``
    appended to their names."""
    out = []
    for m in skinned:
        c = m.copy_with_points(m.points)
        c.name = f"{m.name}{suffix}"
        c.joint_indices, c.joint_weights = m.joint_indices, m.joint_weights
        out.append(c)
    return out


def relax_first_dress(items: list, rest_items: list, rigid: np.ndarray, edges: np.ndarray, body_faces: np.ndarray,
                      rest_body: np.ndarray, body: np.ndarray, passes: int | None = None) -> list:
    """The items dressed in a shot's first pose with no edge longer than the
    strain limit allows against the same items dressed on the bind pose.

    Dressed in the clip's first pose, the reference is posed through its own
    rig and its items follow their binding; where that binding blends body
    parts the pose moves apart, the dress comes out stretched before the
    shot begins: ``ponytail01`` bound to the head and the back together
    (18 mm edges at 35 mm in the CMU walk's first pose, 6-10 cm off the
    skin), ``female_casualsuit02``'s crotch in the run (a 1.5 mm edge at
    6.1 mm). Everything is then bound to that dress, so every frame carries
    the stretch and the per-frame strain limit fights it from scratch. Here
    :class:`strain_limit.StrainLimit` (rest: the bind pose's dress on the
    bind pose's body) shortens them once, with ``passes`` Jacobi passes
    (default ``FIRST_DRESS_PASSES``; it runs once, not per frame).

    Parameters
    ----------
    items : the items dressed in the first pose (meshes, the shot's order).
    rest_items : the same items dressed on the bind pose.
    rigid : (M,) bool over the stacked items, the rigid parts (not moved).
    edges : (E, 2) the stacked items' edges.
    body_faces : (T, 3); rest_body (N, 3) the bind pose's body; body (N, 3)
        the first pose's.

    Returns
    -------
    list: ``items`` with their points relaxed (the same list when the two
    dresses do not match point for point).
    """
    pts = np.concatenate([m.points for m in items]).astype(np.float64)
    rest = np.concatenate([m.points for m in rest_items]).astype(np.float64)
    if rest.shape != pts.shape or rigid.shape != (len(pts),):
        return items
    limit = StrainLimit(rest, edges, body_faces, rest_body, ~rigid,
                        iterations=FIRST_DRESS_PASSES if passes is None else passes)
    limit(body, pts)
    offsets = np.concatenate([[0], np.cumsum([m.n_points for m in items])])
    return [m.copy_with_points(pts[offsets[i]:offsets[i + 1]]) for i, m in enumerate(items)]


def _hem_spans(target: Character, ref_plan: DressPlan, dressed: list, body0: np.ndarray) -> dict:
    """{skirt item: :class:`hem_span.HemSpan`} for the reference's skirts
    (bound from the hips, ``regions.skirt_items``) as dressed statically
    (``dressed``, meshes) on ``body0`` (N, 3), the target's legs and torso by
    its skin weights; empty when there are none or the body has no skin."""
    if ref_plan.regions is None or not ref_plan.regions.skirt_items or target.body.joint_indices is None:
        return {}
    labels = vertex_regions(target.body, target.skeleton)
    legs = np.isin(labels, (R.LEFT_LEG, R.RIGHT_LEG))
    torso = labels == R.TORSO
    if not legs.any() or not torso.any():
        return {}
    out = {}
    for m in dressed:
        if m.name in ref_plan.regions.skirt_items:
            try:
                out[m.name] = HemSpan(m.points, m.faces, body0, legs, torso)
            except ValueError:
                continue   # no hem (a closed mesh)
    return out


def _report_narrow_hems(rep: AnimateReport, hems: dict, outlines: dict, rt) -> None:
    """Record (and say) the frames in which a skirt's hem cannot go round
    the legs at its height (:mod:`hem_span`): there it rides up and the
    legs show, whatever the dressing does."""
    for name, span in hems.items():
        o = outlines[name]
        bad = narrow_frames(o, span.hem)
        if len(bad) == 0:
            continue
        worst = int(bad[np.argmax(o[bad])])
        rep.narrow_hems[name] = {"hem_m": span.hem, "outline_max_m": float(o[worst]), "frames": int(len(bad)),
                                 "first": int(bad[0]), "last": int(bad[-1]), "worst": worst,
                                 "hem_height_m": span.height0}
        info(f"{name}: its hem ({span.hem:.2f} m round, {span.height0:.2f} m over the floor at rest) cannot go "
             f"round the legs at its height in {len(bad)} of {len(o)} frames (output frames {bad[0]}-{bad[-1]}; "
             f"the legs' outline up to {o[worst]:.2f} m at frame {worst}, clip frame "
             f"{float(rt.source_frames[worst]):g}; the cloth stretches {SLACK:g}x at most): a skirt this narrow "
             f"rides up there and the legs below it show (coverage loss)")


def _skinned_whole(ref_plan: DressPlan, opt: AnimateOptions, coarse: bool) -> set:
    """The items a shot skins whole (:class:`_RigidItems`): in bind mode with
    ``rigid_items="skinned"``, the rigid items and the decals on the skin
    (eyebrows; the guard lifted them to its 1 mm margin in every frame, from
    0-1 mm). Not the decals on a coarse body: skinned with the blended
    weights of a 20 cm triangle whose corners follow two joints, a point
    leaves the triangle (RiggedFigure's box head, CMU walk: eyebrows 22 mm
    inside it at frame 0, 92 % of them inside in the worst frame, 0 % bound
    to the triangles)."""
    if opt.mode != "bind" or opt.rigid_items != "skinned":
        return set()
    return ref_plan.wholly_rigid() | (set() if coarse else ref_plan.skin_decals())


def _bind_dress(reference: Character, target: Character, dressed, opt: AnimateOptions, ref_plan):
    """The items dressed statically on the target's bind pose, as `wearfit
    dress` dresses them (untangle pass on; ``dressed`` already is that in
    lbs mode or with ``dress_pose="bind"`` and ``untangle``, otherwise one
    more dressing)."""
    if (opt.mode == "lbs" or opt.dress_pose == "bind") and opt.untangle:
        return dressed
    return dress_items(reference, target, k=opt.k, prepared=ref_plan, pose_align=opt.pose_align)


def _motion_measures(target: Character, dressed, ref_plan) -> MotionMeasures:
    """The motion measures' reference: ``dressed``, the items dressed
    statically on the target's bind pose (:func:`_bind_dress`), with the
    articulated rigid pieces of its plan's rigid groups
    (:func:`dress.item_weights.rigid_pieces`: a shoe's sole and toe cap,
    the hinge between them in neither). The same reference in all modes: bind and
    lbs compare. The loose parts' hanging vertices (cloth weight >= 1/2 on
    the reference's plan, in every mode) are not contacts and may swing
    away from the body they cover."""
    return MotionMeasures(target.body.faces, target.body.points,
                          [(m.name, m.points, m.faces) for m in dressed.items],
                          rigid_pieces(dressed, target),
                          hanging=cloth_weights(ref_plan) >= 0.5)


class _RigidItems:
    """The rigid items of a plan (shoes, hats, glasses: ``names``, see
    :meth:`dress.plan.DressPlan.wholly_rigid`; and the decals on the skin,
    eyebrows, :meth:`dress.plan.DressPlan.skin_decals`) in a shot,
    by linear blend skinning with the weights of their binding
    (:func:`dress.item_weights.skinned_items`: the skin under them; a hat or
    glasses on the head joint alone) from the static dress on the bind pose,
    instead of the binding, a similarity fit per part and the penetration
    guard. A shoe then flexes where the foot does and keeps to it: on the CMU
    walk (ref_female on body_female_thin, 60 frames) the shoes' worst-frame
    stretch beyond the body's p99 2.11x -> 1.00x, max 7.66x -> 1.75x,
    separation p95 10.6 -> 0.6 mm, coverage loss 3.96 % -> 0.31 %, new
    penetrations 0.26 % -> 0 % (the binding's frame evaluation lifted the
    collars off behind the ankles and pushed the toes through the fronts).

    ``skinned``: the shot's items skinned to the bind pose, in its order
    (``order``); ``rows`` (R,) the rigid items' rows among the stacked items
    (``offsets``); ``skinner(skin_mats)`` -> (R, 3) their points.
    ``hinge_rows``: the rows of the items in ``hinged`` (the articulated
    ones: shoes) that are in no rigid piece (a hinge's vertices, weighted
    on two joints)."""

    def __init__(self, skinned: list, names: set, order: list, offsets: np.ndarray, n_joints: int,
                 hinged: set = frozenset()):
        if [m.name for m in skinned] != list(order):
            raise RuntimeError(f"skinned items {[m.name for m in skinned]} not in the shot's order {order}")
        rows, pts, ji, jw, hinge = [], [], [], [], []
        self.names = []
        for i, m in enumerate(skinned):
            if m.name not in names:
                continue
            self.names.append(m.name)
            rows.append(np.arange(offsets[i], offsets[i + 1]))
            pts.append(m.points)
            ji.append(m.joint_indices)
            jw.append(m.joint_weights)
            hinge.append(np.asarray(m.joint_weights).max(axis=1) < PIECE_WEIGHT
                         if m.name in hinged else np.zeros(len(m.points), dtype=bool))
        self.rows = np.concatenate(rows).astype(np.int64)
        self.hinge_rows = self.rows[np.concatenate(hinge)]
        self.skinner = Skinner(np.concatenate(pts), np.concatenate(ji), np.concatenate(jw), n_joints)

    @classmethod
    def of_plan(cls, skinned: list, names: set, plan: DressPlan, n_joints: int) -> _RigidItems:
        """For a shot of ``plan``'s items (its order and rows), the articulated
        ones its wholly rigid items."""
        return cls(skinned, names, [m.name for m in plan.items], plan.offsets, n_joints,
                   hinged=plan.wholly_rigid())


class _SkinnedCopies:
    """The skinned copies of the items (:func:`_skinned_copies`), stacked in
    the order of the motion measures' items (``names``), posed by linear
    blend skinning: ``rows(measures, body_f, mats)`` -> the measures' rows of
    one frame, items renamed ``<item>_skinned``."""

    def __init__(self, skinned: list, n_joints: int, names: list):
        by_name = {m.name.removesuffix(SKINNED_SUFFIX): m for m in skinned}
        ms = [by_name[n] for n in names]
        # one weight source, one influence count: the items stack as they are
        self.skinner = Skinner(np.concatenate([m.points for m in ms]),
                               np.concatenate([m.joint_indices for m in ms]),
                               np.concatenate([m.joint_weights for m in ms]), n_joints)

    def rows(self, measures: MotionMeasures, body_f: np.ndarray, mats: np.ndarray) -> list:
        rows = measures(body_f, self.skinner(mats))
        for r in rows:
            r["item"] = f"{r['item']}{SKINNED_SUFFIX}"
        return rows


def _record(rep: AnimateReport, frame: int | None, rows: list) -> None:
    """Append one measured frame's per-item figures to the report's series
    (``frame`` None: more items of the frame recorded last)."""
    if frame is not None:
        rep.measured_frames.append(int(frame))
    for row in rows:
        series = rep.motion_series.setdefault(row["item"], {k: [] for k in MEASURES})
        for k in MEASURES:
            series[k].append(row[k])


def check_finite_points(points: np.ndarray, frame: int, rt, path) -> None:
    """Raise :class:`NonFiniteError` when the (M, 3) item points of output
    ``frame`` hold NaN/inf (one reduction per frame)."""
    if np.isfinite(points.sum()):
        return
    bad = int(np.flatnonzero(~np.isfinite(points).all(axis=1))[0])
    raise NonFiniteError(path, f"non-finite item point {bad} at output frame {frame} "
                               f"(clip frame {float(rt.source_frames[frame]):g})")


class _FrameWorlds:
    """``(f) -> (J, 4, 4)`` world joint transforms of output frame ``f`` of
    a :class:`retarget.RetargetStream`, computed a block of frames at a time
    (frames asked in increasing order cost one block each);
    ``on_block(first_frame, block)`` is called for every block made."""

    def __init__(self, stream, on_block=None):
        self.stream = stream
        self.on_block = on_block
        self.reset()

    def reset(self):
        self.block = np.empty((0,))
        self.first = 0

    def __call__(self, f: int) -> np.ndarray:
        if not self.first <= f < self.first + len(self.block):
            self.block = self.stream.world(f, f + BLOCK)
            self.first = f
            if self.on_block is not None:
                self.on_block(f, self.block)
        return self.block[f - self.first]


class _LBSEvaluator:
    def __init__(self, points, ji, jw, skin_mats, n_joints):
        self.skinner = Skinner(points, ji, jw, n_joints)
        self.mats = skin_mats

    def __call__(self, f, body_f):
        return self.skinner(self.mats(f))


def dress_items(reference: Character, target: Character, k: int = 5, pose_align: bool = True, **plan_kw):
    """Fit the reference body onto the target body and redress the items
    (:func:`dress.apply.dress`). Returns its :class:`dress.apply.DressResult` (items
    on the target in internal space, plan, timings). ``pose_align=False``: the
    body fit uses similarity alignment only (no skeleton pairing)."""
    if not pose_align:
        plan_kw["body_points"] = fit_character(reference, target, {"pose_align": False}).points
    return dress(reference, target, k=k, **plan_kw)
