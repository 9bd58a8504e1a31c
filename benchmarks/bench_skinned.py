"""Skinned items benchmark: UsdSkel-skinned items against the per-frame redress
(issue 19's "skinned items on every dev target and CMU clip").

`wearfit animate --items both` writes each item twice: the per-frame redress
(point caches) and a copy bound to the target skeleton, posed by UsdSkel
through the shot's SkelAnimation (:func:`dress.item_weights.skinned_items`:
the weights of the K-triangle binding). The shot's report measures both
against the same static dress (the skinned copies by our LBS, equal to
UsdSkel's). Per reference x dev target x clip and item: the worst frame's
new penetrations of the two, their difference (issue 19's limit: within 1
percentage point), the stretch p99 and coverage loss (a skinned skirt's
web between the legs), the separation p95 and the rigid parts' distance from
a similarity (issue 17's 2 mm; shoes and hats are written skinned in
both, with articulated weights). The copies' rest points are fitted to
example poses (:mod:`animate.skin_fit`), made once per reference and
target for every clip. Quick: the CMU walk, the first 60 frames at 30 fps,
measured every frame, on ref_male, ref_female and ref_female_longskirt (its
skirt's skinned copy takes the legs' skin below the hips:
:mod:`dress.skirt_weights`) x the 10 dev targets;
full: every CMU clip (the first 60 frames of each), every 2nd frame. The
loose parts that get joints of their own (:mod:`animate.item_joints`, a
ponytail, a jacket's hem) are measured in the same shot with the skin's
weights too (``skin_weights_new_pen_pct``, the baseline).

Run alone: ``python3 benchmarks/bench_skinned.py [--full]``.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import BVH_DIR, DEFAULT_OUT, USD_DIR, clip_end, format_table  # noqa: E402

REFS = ("ref_male.usda", "ref_female.usda", "ref_female_longskirt.usda")
FRAMES = 60


def targets() -> list[Path]:
    return sorted(USD_DIR.glob("body_*.usdc"))


def run(full: bool, out_dir: Path, measure_every: int | None = None) -> list[dict]:
    from wearfit_usd.animate.skin_fit import training_frames
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.dress.plan import plan as plan_dress
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    clips = sorted(BVH_DIR.glob("cmu*.bvh")) if full else [BVH_DIR / "cmu_07_01_walk.bvh"]
    if measure_every is None:
        measure_every = 2 if full else 1
    motions = {clip: read_bvh(clip) for clip in clips}
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for ref_name in REFS:
        ref = read_character(USD_DIR / ref_name)
        ref_plan = plan_dress(ref, k=5)
        for tgt_path in targets():
            tgt = read_character(tgt_path)
            # the skinned copies' example poses depend on the reference and the target, not the clip
            t0 = time.perf_counter()
            examples = training_frames(ref, tgt, ref_plan, AnimateOptions())
            examples_s = time.perf_counter() - t0
            for clip, motion in motions.items():
                t0 = time.perf_counter()
                rep = animate(ref, tgt, motion, out_dir / "skinned_shot.usdc",
                              AnimateOptions(start=1, end=clip_end(motion, FRAMES), items="both",
                                             measure_every=measure_every, skin_examples=examples,
                                             compare_item_joints=True),
                              ref_plan=ref_plan)
                secs = time.perf_counter() - t0
                for item in ref.items:
                    a, b = rep.motion_worst[item.name], rep.motion_worst[item.name + "_skinned"]
                    pa, pb = a["new_pen_pct"]["value"], b["new_pen_pct"]["value"]
                    # the same copy with the skin's weights, where it is on joints of its own (same shot)
                    c = rep.motion_worst.get(item.name + "_skinned_without_joints")
                    pc = None if c is None else round(c["new_pen_pct"]["value"], 3)
                    joints = rep.item_joints.get(item.name + "_skinned", 0)
                    rows.append({"ref": ref_name.removesuffix(".usda"), "target": tgt_path.stem,
                                 "clip": clip.stem, "frames": rep.frames, "item": item.name,
                                 "redress_new_pen_pct": round(pa, 3), "skinned_new_pen_pct": round(pb, 3),
                                 "skinned_minus_redress_pp": round(pb - pa, 3),
                                 "within_1pp": bool(pb - pa <= 1.0),
                                 "item_joints": joints, "skin_weights_new_pen_pct": pb if pc is None else pc,
                                 "skin_weights_within_1pp": bool((pb if pc is None else pc) - pa <= 1.0),
                                 "redress_sep_p95_mm": _r(a["separation_p95_mm"]["value"]),
                                 "skinned_sep_p95_mm": _r(b["separation_p95_mm"]["value"]),
                                 "redress_stretch_p99": _r(a["stretch_p99"]["value"]),
                                 "skinned_stretch_p99": _r(b["stretch_p99"]["value"]),
                                 "redress_coverage_loss_pct": _r(a["coverage_loss_pct"]["value"]),
                                 "skinned_coverage_loss_pct": _r(b["coverage_loss_pct"]["value"]),
                                 "redress_rigid_mm": _r(a["rigid_mm"]["value"]),
                                 "skinned_rigid_mm": _r(b["rigid_mm"]["value"]),
                                 "shot_seconds": round(secs, 1), "example_poses_seconds": round(examples_s, 1)})
    (out_dir / "skinned_shot.usdc").unlink(missing_ok=True)
    return rows


def _r(v):
    return None if v is None else round(float(v), 2)


if __name__ == "__main__":
    print(format_table(run("--full" in sys.argv, DEFAULT_OUT)))
