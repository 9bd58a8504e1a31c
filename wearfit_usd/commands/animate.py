"""`wearfit animate REFERENCE TARGET CLIP.bvh -o SHOT.usd`: dynamic try-on."""
from __future__ import annotations

import argparse

from ..errors import InputError
from .args import (
    MAX_FRAMES,
    bounded_float,
    bounded_int,
    check_distinct,
    check_inputs,
    check_output,
    fps_arg,
    start_arg,
    write_report,
)
from .output_options import add_carry_options
from .targets import add_target_options, load_target


def register(sub, common):
    p = sub.add_parser(
        "animate", parents=[common],
        help="dress TARGET with REFERENCE's items and animate it with a BVH clip into one USD shot",
        description="Retarget CLIP onto TARGET's skeleton, dress frame 0 with REFERENCE's items, "
                    "re-evaluate the item binding every frame and write one USD shot: the target body "
                    "with its SkelAnimation and every item as a mesh with time-sampled points.")
    p.add_argument("reference", help="USD stage with the reference body and its wearable items")
    p.add_argument("target", help="USD stage with the rigged target body")
    p.add_argument("clip", help="BVH motion clip")
    p.add_argument("-o", "--output", required=True, help="output USD shot (.usd/.usda/.usdc)")
    p.add_argument("--k", type=bounded_int(1, 64), default=5, help="triangles each item vertex is bound to (default 5)")
    p.add_argument("--start", type=start_arg, default=None,
                   help="first clip frame, or 'auto' (default): 1 when frame 0 is a converter's rest pose "
                        "(the T-pose frame 0 of CMU conversions), else 0")
    p.add_argument("--end", type=int, default=None, help="last clip frame (exclusive)")
    p.add_argument("--fps", type=fps_arg, default=30.0,
                   help="output frame rate, or 'native' for the clip's (default 30)")
    p.add_argument("--max-frames", type=bounded_int(1), default=MAX_FRAMES,
                   help=f"refuse shots of more output frames than this (default {MAX_FRAMES})")
    p.add_argument("--map", dest="mapping", default=None,
                   help="JSON joint map {target_joint: clip_joint} overriding the automatic mapping")
    p.add_argument("--floor", choices=["auto", "keep"], default="auto",
                   help="auto: move the clip up or down so the body's lowest point at the first frame is on "
                        "its rest floor (one constant shift: the clip's own vertical motion is kept; "
                        "default); keep: the clip's heights as retargeted")
    p.add_argument("--no-pose", action="store_true",
                   help="dress with the reference body fitted by similarity alignment only (no pairing of the "
                        "reference's and the target's skeletons); the clip must still pair with the target")
    p.add_argument("--bvh-scale", type=bounded_float(0.0, 1e3), default=None,
                   help="metres per BVH unit (default: detected)")
    p.add_argument("--mode", choices=["bind", "lbs"], default="bind",
                   help="bind: K-triangle binding per frame (default); lbs: skin weights copied to the items")
    p.add_argument("--dress-pose", choices=["auto", "first", "bind"], default="auto",
                   help="first: dress in the clip's first frame pose (reference posed through its own rig, "
                        "fitted onto the posed target); bind: dress on the bind pose as `wearfit dress` does "
                        "and reach frame 0 through the binding (contacts at frame 0 then stay temporary); "
                        "auto (default): bind for a coarse (low-poly) body of another topology, else first")
    p.add_argument("--untangle", action="store_true",
                   help="run dressing's untangle pass on frame 0 too (off by default: on the CMU pirouette it "
                        "raised the worst frame's new penetrations from 0.31 %% to 0.33 %%)")
    p.add_argument("--cloth", action=argparse.BooleanOptionalAction, default=None,
                   help="simulate the loose parts (skirts, dresses, coat tails, long hair) as XPBD cloth hanging "
                        "from their attachment, the body as collider (default: on when the items have loose parts; "
                        "bind mode only)")
    p.add_argument("--strain-limit", action=argparse.BooleanOptionalAction, default=True,
                   help="bind mode: shorten item edges stretched beyond 1.1x the body's own stretch under them "
                        "after the frame's other passes, never into the body (default: on)")
    p.add_argument("--contact-hold", action=argparse.BooleanOptionalAction, default=True,
                   help="bind mode: hold a skirt's bound parts on the skin they touch in the static dress (its "
                        "binding hangs from the hips above the buttocks: bent forward, the back stood 5 cm off "
                        "them) (default: on)")
    p.add_argument("--layer-hold", action=argparse.BooleanOptionalAction, default=True,
                   help="bind mode: keep each frame's outer layers over the items under them, surface against "
                        "surface (a top's hem over a skirt's waistband) (default: on)")
    p.add_argument("--no-item-joints", action="store_true",
                   help="--items skinned|both: the skinned items' loose parts (a hanging ponytail, a suit's loose "
                        "hems) keep the skin's weights; by default they get joints of their own, appended to the "
                        "skeleton and animated from the per-frame cloth, where the example poses show it helps (as "
                        "engines rig hair joints); skirts and dresses keep the skin's weights either way")
    p.add_argument("--rigid-items", choices=("skinned", "bound"), default="skinned",
                   help="bind mode: rigid items (shoes, hats, glasses) and decals on the skin (eyebrows) follow "
                        "the skeleton by skinning with their "
                        "binding's weights (default; a shoe flexes with the foot and keeps to it), or are bound "
                        "like the rest, fitted rigidly per part and pushed out of the body (the older way: the "
                        "toes came through the shoes)")
    p.add_argument("--write-skinned-items", action="store_true",
                   help="the same as --items both (its older name)")
    p.add_argument("--velocities", action="store_true", help="author point velocities (units per second)")
    p.add_argument("--clip-frames", type=bounded_int(1), default=None,
                   help="write item samples as USD value clips of N frames (default: automatic for long shots)")
    p.add_argument("--report", default=None,
                   help="write a JSON report here (timings, and per item and measured frame the motion "
                        "measures: stretch beyond the body's own, separation, coverage loss, rigid parts, "
                        "new penetrations, against the items dressed statically on the target) and print "
                        "the worst frame of each measure per item")
    p.add_argument("--strict", action="store_true",
                   help="fail (exit code 1) when a motion measure's worst frame is over its limit "
                        "(stretch p99 1.15x / max 1.5x the body's own, coverage loss 2 %%, separation p95 "
                        "15 mm, rigid parts 2 mm, new penetrations 1 %%); the shot and report are still written")
    p.add_argument("--measure-every", type=int, default=None, metavar="N",
                   help="measure every Nth frame (and the last); default 1 with --report or --strict, "
                        "else no measuring")
    add_carry_options(p)
    add_target_options(p, items_default="points")
    p.set_defaults(func=run)
    return p


def _carry_plan(reference, target, args):
    """What the inputs carry onto the shot's meshes: the items, and with
    ``--items skinned|both`` their skinned copies (named as the shot names
    them) too."""
    from dataclasses import replace

    from ..io.usd_carry import CarryPlan
    from ..model import SKINNED_SUFFIX
    plan = CarryPlan.for_dress(reference, target, reference.items, reference_inputs=args.reference_inputs)
    mode = "both" if args.write_skinned_items and args.items == "points" else args.items
    if mode == "points":
        return plan
    suffix = SKINNED_SUFFIX if mode == "both" else ""
    copies = []
    for m in reference.items:
        c = m.copy_with_points(m.points)
        c.name = f"{m.name}{suffix}"
        copies.append(c)
    extra = CarryPlan.for_dress(reference, target, copies, reference_inputs=args.reference_inputs).items
    return replace(plan, items={**extra, **plan.items})


def run(args) -> int:
    from ..animate.measures import MotionLimitError, MotionLimits, describe_worst
    from ..animate.try_on import AnimateOptions, animate
    from ..io.bvh import read_bvh
    from ..io.usd import read_character
    from ..progress import info
    fps = args.fps
    check_inputs(args.reference, args.target, args.clip, args.mapping)
    inputs = (args.reference, args.target, args.clip, args.mapping)
    check_output(args.output, inputs)
    if args.report:
        check_output(args.report, inputs, suffixes=(), what="--report")
        check_distinct({"-o": args.output, "--report": args.report})
    reference = read_character(args.reference)
    target, _ = load_target(reference, args.target, args.rig_from_reference, pose_align=not args.no_pose)
    motion = read_bvh(args.clip, scale=args.bvh_scale)
    mapping = None
    if args.mapping:
        from ..motion.joint_maps import load_user_map
        mapping = load_user_map(args.mapping, source_names=motion.joint_names,
                                target_names=target.skeleton.joint_names if target.skeleton else None)
    every = args.measure_every
    if every is None:
        every = 1 if (args.report or args.strict) else 0
    if every < 0:
        raise InputError(None, f"--measure-every must be 0 or more, got {every}")
    if args.strict and every == 0:
        raise InputError(None, "--strict needs measuring: --measure-every 0 turns it off")
    opts = AnimateOptions(k=args.k, start=args.start, end=args.end, fps=fps, mode=args.mode,
                          mapping=mapping, clip_frames=args.clip_frames, velocities=args.velocities,
                          items="both" if args.write_skinned_items and args.items == "points" else args.items,
                          dress_pose=args.dress_pose,
                          untangle=args.untangle, measure_every=every, floor=args.floor,
                          pose_align=not args.no_pose, cloth=args.cloth,
                          max_frames=args.max_frames,
                          carry_plan=_carry_plan(reference, target, args),
                          hidden_body="delete" if args.delete_hidden_body else "subset",
                          rigid_items=args.rigid_items, strain_limit=args.strain_limit,
                          contact_hold=args.contact_hold, layer_hold=args.layer_hold, skin_fit=not args.no_skin_fit,
                          item_joints=not args.no_item_joints)
    rep = animate(reference, target, motion, args.output, opts)
    t = rep.timings
    info(f"wrote {args.output}: {rep.frames} frames at {rep.fps:g} fps, {len(reference.items)} items; "
         f"total {t['total']:.2f} s (binding evaluation {t['evaluate_fps']:.0f} frames/s, "
         f"LBS {t['lbs_fps']:.0f} frames/s, writing {t['write_fps']:.0f} frames/s)")
    if rep.cloth_vertices:
        info(f"cloth: {rep.cloth_vertices} loose item vertices simulated, "
             f"{1000 * t['cloth_total'] / max(rep.frames - 1, 1):.2f} ms/frame")
    if args.report:
        write_report(args.report, rep.as_dict())
    limits = MotionLimits()
    if rep.motion_worst:
        info(f"worst measured frame per item ({len(rep.measured_frames)} frames measured; "
             "! = over the limit):")
        for item, figs in rep.motion_worst.items():
            info("  " + describe_worst(item, figs, limits))
    if args.strict:
        bad = limits.violations(rep.motion_worst)
        if bad:
            raise MotionLimitError(args.output, "motion measures over their limits (the shot was written): "
                                   + "; ".join(bad))
    return 0
