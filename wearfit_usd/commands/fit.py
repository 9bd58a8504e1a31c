"""`wearfit fit REFERENCE TARGET -o FITTED.usd`: the reference body mesh
(its topology, rig and skin weights) deformed onto the target body."""
from __future__ import annotations

from .args import check_distinct, check_inputs, check_output, write_report
from .output_options import add_carry_options


def register(sub, common):
    p = sub.add_parser(
        "fit", parents=[common],
        help="deform the reference body (topology, rig, skin weights) onto a target body",
        description="Deform the reference body mesh onto the target body automatically (no "
                    "landmarks): pose alignment through the skeletons, then non-rigid "
                    "registration. Writes the reference topology, skin weights and skeleton "
                    "(joints moved onto the target's) in the target's up axis and units.")
    p.add_argument("reference", help="reference rigged USD stage (its skinned body is fitted)")
    p.add_argument("target", help="target USD stage (rigged, or any mesh with --no-skeleton)")
    p.add_argument("-o", "--output", required=True, help="output .usd/.usda/.usdc")
    p.add_argument("--no-pose", action="store_true",
                   help="skip the skeleton pose step (global similarity only)")
    p.add_argument("--force-registration", action="store_true",
                   help="run the non-rigid registration even when the topologies are equal")
    p.add_argument("--report", metavar="JSON", help="also write the fit diagnostics as JSON")
    add_carry_options(p, hidden=False)
    p.set_defaults(func=run)
    return p


def fitted_character(ref, target, result):
    """A Character holding the fitted reference body: reference topology and
    skin weights, reference skeleton re-bound at the posed joint transforms
    (mapped joints on the target's joints), target up axis/units."""
    from ..fit.rig import fitted_skeleton
    from ..model import Character

    skel = None if ref.skeleton is None else fitted_skeleton(ref.skeleton, result.joint_world)
    body = ref.body.copy_with_points(result.points)
    return Character(source=str(target.source), up_axis=target.up_axis,
                     meters_per_unit=target.meters_per_unit, to_internal=target.to_internal,
                     skeleton=skel, body=body, items=[],
                     time_codes_per_second=target.time_codes_per_second)


def run(args) -> int:
    from ..fit.body_fit import fit_character
    from ..io.usd import read_character, write_character
    from ..progress import info, warn

    check_inputs(args.reference, args.target)
    out = check_output(args.output, (args.reference, args.target))
    if args.report:
        check_output(args.report, (args.reference, args.target), suffixes=(), what="--report")
        check_distinct({"-o": out, "--report": args.report})
    ref = read_character(args.reference)
    target = read_character(args.target, require_skeleton=False)
    opts = {"pose_align": not args.no_pose,
            "same_topology_shortcut": not args.force_registration}
    result = fit_character(ref, target, opts)
    for w in result.warnings:
        warn(w)
    char = fitted_character(ref, target, result)
    from ..io.usd_carry import CarryPlan
    plan = CarryPlan.for_dress(ref, target, [], reference_inputs=args.reference_inputs, body_from_reference=True)
    write_character(out, char, items=[], up_axis=target.up_axis,
                    meters_per_unit=target.meters_per_unit, carry_plan=plan)
    d = result.diagnostics
    jm = d.get("joint_match")
    if jm and not jm["by_names"]:
        info(f"joints paired by role (names and structure): {d.get('joint_pairs', 0)} pairs, "
             f"confidence {jm['confidence']:.2f}; `wearfit inspect {args.reference} --map {args.target}` "
             "lists them")
    if result.same_topology:
        info(f"{out}: same topology as the target: fitted = target points "
             f"({d['ref_vertices']} vertices)")
    else:
        info(f"{out}: fitted {d['ref_vertices']} vertices onto {d['target_vertices']} in "
             f"{d['time_total_fit_s']:.2f} s ({d['alignment']}, {d['iterations']} iterations, "
             f"{d['solver']}); distance fit->target mean {d['fit_to_target_mean_mm']:.2f} mm "
             f"p99 {d['fit_to_target_p99_mm']:.2f} mm, target->fit mean "
             f"{d['target_to_fit_mean_mm']:.2f} mm p99 {d['target_to_fit_p99_mm']:.2f} mm, "
             f"{d['flipped_triangles']} flipped triangles")
    if args.report:
        write_report(args.report, {"diagnostics": d, "warnings": result.warnings,
                                   "same_topology": result.same_topology})
    return 0
