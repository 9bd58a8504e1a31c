"""`wearfit dress REFERENCE TARGET -o OUT.usd`: put the reference's items on the target body."""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .args import K_MAX, bounded_int, check_distinct, check_inputs, check_output, write_report
from .output_options import add_carry_options, write_dressed
from .targets import add_target_options, load_target


def register(sub, common):
    p = sub.add_parser(
        "dress", parents=[common],
        help="put every wearable item of a reference stage on a target body",
        description="Bind every item of REFERENCE to its body (k nearest triangles, local frames, "
                    "regions from skin weights), carry it onto TARGET's body, push out "
                    "penetrations, and write the target body (rigged, as read) with the items.")
    p.add_argument("reference", help="USD stage with the rigged reference body and its items")
    p.add_argument("target", help="USD stage with the rigged target body")
    p.add_argument("-o", "--output", required=True, help="output USD file (.usd/.usda/.usdc)")
    p.add_argument("--k", type=bounded_int(1, K_MAX), default=5,
                   help="body triangles per item vertex (default 5)")
    p.add_argument("--rigid", default="auto",
                   help="items moved by a best-fit similarity transform instead of free deformation: "
                        "'auto' (small stiff parts: shoes, hat, glasses, watch...), 'none', or a "
                        "comma-separated list of item names (default auto)")
    p.add_argument("--no-regions", action="store_true",
                   help="do not restrict bindings to one body region (legs/arms/torso/head)")
    p.add_argument("--no-push-out", action="store_true", help="skip the penetration pass")
    p.add_argument("--fix-reference-penetrations", action="store_true",
                   help="push item vertices that were already more than 1 mm inside the reference body "
                        "out to 1 mm, so no skin shows through (default: they keep their reference "
                        "clearance, as every other vertex; the repair shortens the edges of folds that "
                        "dipped into the body)")
    p.add_argument("--report", default=None, metavar="FILE.json",
                   help="write per-item fit figures (new penetrations, clearance change, flipped "
                        "triangles, over-stretched edges) and timings as JSON")
    p.add_argument("--no-pose", action="store_true",
                   help="fit the reference body by similarity alignment only (no skeleton pairing); "
                        "needed when the two skeletons' key joints cannot be paired")
    p.add_argument("--strict", action="store_true",
                   help="fail (instead of warning) when an item lies more than 0.5 m from the body")
    add_carry_options(p)
    add_target_options(p, items_default="both")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..dress.apply import dress
    from ..io.usd import read_character
    from ..progress import info

    ref_path, tgt_path, out = Path(args.reference), Path(args.target), Path(args.output)
    check_inputs(ref_path, tgt_path)
    check_output(out, (ref_path, tgt_path))
    if args.report:
        check_output(args.report, (ref_path, tgt_path), suffixes=(), what="--report")
        check_distinct({"-o": out, "--report": args.report})
    ref = read_character(ref_path)
    target, fitted = load_target(ref, tgt_path, args.rig_from_reference, pose_align=not args.no_pose)
    if not ref.items:
        raise InputError(ref_path, "the reference holds no wearable items (no Mesh besides the body)")
    rigid = args.rigid
    if rigid not in ("auto", "none"):
        rigid = [s.strip() for s in rigid.split(",") if s.strip()]
        unknown = [n for n in rigid if n not in [m.name for m in ref.items]]
        if unknown:
            raise InputError(ref_path, f"--rigid names unknown items {unknown}; items: "
                                       f"{[m.name for m in ref.items]}")
    body_points = fitted
    if args.no_pose and body_points is None:
        from ..fit.body_fit import fit_character
        body_points = fit_character(ref, target, {"pose_align": False}).points
    res = dress(ref, target, k=args.k, use_regions=not args.no_regions, rigid=rigid,
                penetration=not args.no_push_out, strict_far=args.strict,
                push_inherited=args.fix_reference_penetrations, body_points=body_points)
    points, skinned, hidden = write_dressed(out, ref, target, res, args.items,
                                            reference_inputs=args.reference_inputs,
                                            delete_hidden_body=args.delete_hidden_body,
                                            skin_fit=not args.no_skin_fit, pose_align=not args.no_pose)
    t = res.timings
    if args.report:
        from ..dress.metrics import dress_report
        rows = dress_report(ref, target, res)
        write_report(args.report, {"reference": str(ref_path), "target": str(tgt_path),
                                   "output": str(out), "items": rows, "timings_s": t})
        for r in rows:
            info(f"  {r['item']:<24} new penetrations {r['new_pen_pct']:.2f} %, clearance change "
                 f"median {r['clear_med_mm']:.2f} mm, p95 {r['clear_p95_mm']:.2f} mm, flipped "
                 f"{r['flipped_pct']:.2f} %, edges beyond the body's stretch {r['overstretch_pct']:.2f} %")
    info(f"wrote {out}: {len(res.items)} items ({res.points.shape[0]} vertices) on "
         f"{tgt_path.name}; rigid: {', '.join(res.plan.rigid_items) or '-'}; "
         f"skirt-like: {', '.join(res.plan.regions.skirt_items) or '-'}; "
         f"pushed out {int(res.moved.sum())} vertices; bind {t['bind_s']:.3f} s, "
         f"evaluate {t['evaluate_s'] * 1000:.1f} ms, penetration {t['penetration_s']:.3f} s"
         + (f", untangle {t['untangle_s']:.3f} s" if "untangle_s" in t else "") + f"; {hidden}")
    if skinned:
        info(f"  items as {args.items}: " + ("points under /Root/Items, " if points else "")
             + "skinned to the target skeleton inside the SkelRoot "
             f"({', '.join(m.name for m in skinned)})")
    return 0
