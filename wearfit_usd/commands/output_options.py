"""Output options shared by `fit`, `dress` and `animate`: what the written
stage keeps of its inputs (:mod:`wearfit_usd.io.usd_carry`) and the body
hidden under the items (:mod:`wearfit_usd.dress.hidden_body`)."""
from __future__ import annotations


def add_carry_options(p, hidden: bool = True) -> None:
    """``--reference-inputs`` (and with ``hidden`` ``--delete-hidden-body``) on parser ``p``."""
    p.add_argument("--reference-inputs", action="store_true",
                   help="reference the input files' prims (materials, UVs, attributes) instead of copying "
                        "them, so edits of the inputs flow through; the output authors only the computed "
                        "points, normals and skinning")
    if hidden:
        p.add_argument("--delete-hidden-body", action="store_true",
                       help="write the body without the faces the items cover (for engines; weights, UVs "
                            "and other primvars re-indexed) instead of naming them in the GeomSubset "
                            "hidden_under_items")


def dress_output(reference, target, items, reference_inputs: bool = False, delete_hidden_body: bool = False):
    """(body to write, CarryPlan, one-line summary) of a `dress` output:
    the target body with its hidden subsets (or without the hidden faces).
    `wearfit dress` and `wearfit batch` both write through this."""
    from ..dress.hidden_body import hide_or_drop
    from ..io.usd_carry import CarryPlan
    plan = CarryPlan.for_dress(reference, target, items, reference_inputs=reference_inputs)
    body, subsets, keep = hide_or_drop(target.body, target.body.points,
                                       [(m.name, m.points, m.faces) for m in items],
                                       delete=delete_hidden_body)
    plan = plan.with_hidden(subsets, keep)
    if keep is not None:
        what = f"body written without {int((~keep).sum())} hidden faces of {len(keep)}"
    else:
        what = f"{len(subsets['hidden_under_items'])} body faces hidden under the items"
    return body, plan, what


def write_dressed(out, reference, target, result, items: str = "both", reference_inputs: bool = False,
                  delete_hidden_body: bool = False, skin_fit: bool = True, ref_plan=None, pose_align: bool = True):
    """Write a dressing ``result`` on ``target`` as `wearfit dress` does (and
    `wearfit batch` with it): the body with its hidden subsets, the items as
    ``items`` (points, skinned or both), the inputs' materials and primvars
    carried onto each written mesh. With ``skin_fit`` the skinned items'
    rest points are fitted to example poses (:mod:`animate.skin_fit`; the
    reference's dressing plan ``ref_plan`` reused when given). Returns
    (point items, skinned items, one-line summary of the hidden body)."""
    from dataclasses import replace

    from ..io.usd import write_character
    from ..io.usd_carry import CarryPlan
    from .targets import output_items
    body, plan, hidden = dress_output(reference, target, result.items, reference_inputs=reference_inputs,
                                      delete_hidden_body=delete_hidden_body)
    frames = None
    if skin_fit and items != "points":
        import time

        from ..animate.skin_fit import TRAINING_CLIPS, example_frames
        from ..animate.try_on import AnimateOptions
        from ..progress import info
        t0 = time.perf_counter()
        frames = example_frames(reference, target, ref_plan, AnimateOptions(pose_align=pose_align))
        if frames is not None:
            info(f"skinned items: {len(frames[0])} example poses ({', '.join(TRAINING_CLIPS)}) dressed in "
                 f"{time.perf_counter() - t0:.1f} s to fit their rest points (--no-skin-fit skips)")
    points, skinned = output_items(result, target, items, skin_frames=frames)
    if skinned:  # the skinned copies carry their items' materials and primvars too
        extra = CarryPlan.for_dress(reference, target, skinned, reference_inputs=reference_inputs).items
        plan = replace(plan, items={**extra, **plan.items})
    write_character(out, target, items=points + skinned, body=body, carry_plan=plan, skinned_items=bool(skinned))
    return points, skinned, hidden
