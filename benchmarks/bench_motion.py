"""Motion benchmark: items keeping their shape in motion (issue 17).

`wearfit animate` with the motion measures (:mod:`wearfit_usd.animate.measures`:
stretch beyond the body's own, separation, coverage loss, rigid parts, new
penetrations, against the items dressed statically on the same target) on
every frame, the K-triangle binding (``--mode bind``) and the LBS baseline
(``--mode lbs``) in the same run. One row per clip, reference, target, mode
and item: the worst frame of each measure (value and frame), ``over`` the
measures beyond :class:`MotionLimits`; then one summary row per reference,
item and mode: the worst over every clip and target.

Full: every CMU clip in ../shared/data/bvh on the dev references
(ref_female_longskirt, ref_female, ref_male) and every body_*.usdc of the
matching sex, whole clips at 30 fps. Quick: three pairs, two clips, the
first 60 frames at 30 fps. Each clip starts where `wearfit animate` starts it
by default (``--start auto``: past the frames that blend from a converter's
T-pose, clip frame 4 of cmudaz_02_02_walk; 1 on the CMU clips with a T-pose
frame 0, 0 on cmu3dsmax_131_01_start_walk_stop). Every shot of a reference with a loose garment
(the long skirt) is rendered with `wearfit render` into
``<out>/motion_render/<shot>/`` and its contact sheet copied to
``<out>/motion_<shot>.png`` (the report embeds it).

Every clip: ``--every-clip`` runs every CMU clip, whole, at 30 fps on one
target per reference and on ``ref_male``'s two (:data:`SWEEP_PAIRS`), the binding
only, the measures on every second frame (about 6,700 frames, 18 minutes on one core).

Run alone: ``python3 benchmarks/bench_motion.py [--full | --every-clip]``.
"""
from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import BVH_DIR, DEFAULT_OUT, USD_DIR, clip_end, format_table  # noqa: E402

REFERENCES = {"ref_female_longskirt.usda": "female", "ref_female.usda": "female", "ref_male.usda": "male"}
LOOSE = {"ref_female_longskirt.usda"}  # references whose shots get a contact sheet
QUICK_PAIRS = [("ref_female_longskirt.usda", "body_female_heavy.usdc"),
               ("ref_female.usda", "body_female_thin.usdc"),
               ("ref_male.usda", "body_male_muscular_heavy.usdc")]
QUICK_CLIPS = ["cmu_07_01_walk.bvh", "cmu_05_12_dance_arms_held_high.bvh"]
QUICK_FRAMES = 60
MODES = ("bind", "lbs")
SWEEP_PAIRS = [("ref_female_longskirt.usda", "body_female_heavy.usdc"),
               ("ref_female.usda", "body_female_thin.usdc"),
               ("ref_male.usda", "body_male_heavy.usdc"),
               # the quick table's male target too: a change to the strain limit
               # passed the sweep and tore the suit on this body (session 33)
               ("ref_male.usda", "body_male_muscular_heavy.usdc")]


def targets(sex: str) -> list[str]:
    """The dev targets of one sex: every body_<sex>_*.usdc."""
    return sorted(p.name for p in USD_DIR.glob(f"body_{sex}_*.usdc"))


def cases(full: bool, every_clip: bool = False) -> list[tuple[str, str, str]]:
    """(clip, reference, target) triples."""
    clips = sorted(p.name for p in BVH_DIR.glob("cmu*.bvh"))
    if full:
        return [(c, r, t) for r, sex in REFERENCES.items() for t in targets(sex) for c in clips]
    if every_clip:
        return [(c, r, t) for r, t in SWEEP_PAIRS for c in clips]
    return [(c, r, t) for r, t in QUICK_PAIRS for c in QUICK_CLIPS]


def run_shot(clip: str, ref_name: str, body_name: str, mode: str, out_dir: Path, frames: int | None,
             measure_every: int = 1):
    """Animate one shot with the measures on every frame; returns (shot path,
    AnimateReport, seconds)."""
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    from wearfit_usd.motion.clip_start import leading_rest_frames
    ref = read_character(USD_DIR / ref_name)
    tgt = read_character(USD_DIR / body_name)
    motion = read_bvh(BVH_DIR / clip)
    # where `wearfit animate` starts the clip by default (--start auto): a
    # shot from clip frame 1 of the Daz walk jumped from a T-pose blend to
    # walking in one frame (its worst frames were frame 2 on every item)
    start = leading_rest_frames(motion)
    end = None if frames is None else clip_end(motion, frames, start=start)
    shot = out_dir / f"motion_{Path(clip).stem}_{Path(ref_name).stem}_{Path(body_name).stem}_{mode}.usdc"
    t0 = time.perf_counter()
    rep = animate(ref, tgt, motion, shot, AnimateOptions(start=start, end=end, fps=30, mode=mode,
                                                         measure_every=measure_every))
    return shot, rep, time.perf_counter() - t0


def item_rows(clip: str, ref_name: str, body_name: str, mode: str, rep, seconds: float) -> list[dict]:
    """One table row per item: the worst frame of each measure."""
    from wearfit_usd.animate.measures import MEASURES, MotionLimits
    limits = MotionLimits()
    rows = []
    for item, figs in rep.motion_worst.items():
        row = {"clip": clip, "ref": ref_name, "body": body_name, "mode": mode, "item": item,
               "frames": rep.frames}
        for key in MEASURES:
            row[key] = figs[key]["value"]
            row[f"{key}_f"] = figs[key]["frame"]
        row["over"] = ",".join(v.split(": ")[1].split(" ")[0] for v in limits.violations({item: figs})) or "-"
        row["shot_s"] = seconds
        rows.append(row)
    return rows


def summary_rows(rows: list[dict]) -> list[dict]:
    """Per reference, item and mode: the worst value of each measure over
    every clip and target, and where it was."""
    from wearfit_usd.animate.measures import MEASURES, MotionLimits
    limits = MotionLimits()
    out = {}
    for r in rows:
        key = (r["ref"], r["item"], r["mode"])
        s = out.setdefault(key, {"clip": "WORST OF ALL", "ref": r["ref"], "body": "", "mode": r["mode"],
                                 "item": r["item"], "frames": 0})
        s["frames"] += r["frames"]
        for m in MEASURES:
            v = r[m]
            if v is not None and (s.get(m) is None or v > s[m]):
                s[m] = v
                s[f"{m}_f"] = f"{Path(r['clip']).stem}/{Path(r['body']).stem}#{r[f'{m}_f']}"
    res = []
    for s in out.values():
        figs = {m: {"value": s.get(m), "frame": s.get(f"{m}_f")} for m in MEASURES}
        s["over"] = ",".join(v.split(": ")[1].split(" ")[0]
                             for v in limits.violations({s["item"]: figs})) or "-"
        res.append(s)
    return sorted(res, key=lambda s: (s["ref"], s["item"], s["mode"]))


def contact_sheet(shot: Path, out_dir: Path) -> Path | None:
    """`wearfit render SHOT -o DIR` (320x240); the contact sheet copied to
    out_dir/<shot stem>.png."""
    from wearfit_usd.cli import main
    dest = out_dir / "motion_render" / shot.stem
    rc = main(["render", str(shot), "-o", str(dest), "--size", "320x240", "-q"])
    sheet = dest / "contact_sheet.png"
    if rc != 0 or not sheet.exists():
        return None
    png = out_dir / f"{shot.stem}.png"
    shutil.copyfile(sheet, png)
    return png


def run(full: bool, out_dir: Path, every_clip: bool = False) -> list[dict]:
    from wearfit_usd.progress import set_verbosity
    out_dir.mkdir(parents=True, exist_ok=True)
    set_verbosity(0)
    rows = []
    whole = full or every_clip
    for clip, ref, body in cases(full, every_clip):
        for mode in (("bind",) if every_clip else MODES):
            shot, rep, secs = run_shot(clip, ref, body, mode, out_dir, None if whole else QUICK_FRAMES,
                                       measure_every=2 if every_clip else 1)
            rows += item_rows(clip, ref, body, mode, rep, secs)
            if ref in LOOSE:
                contact_sheet(shot, out_dir)
            if whole:  # thousands of frames: keep the disk use bounded
                shot.unlink(missing_ok=True)
                shutil.rmtree(shot.with_suffix(".clips"), ignore_errors=True)
    return rows + summary_rows(rows)


if __name__ == "__main__":
    full = "--full" in sys.argv
    out = DEFAULT_OUT
    rows = run(full, out, every_clip="--every-clip" in sys.argv)
    print(format_table(rows))
    (out / "motion.json").write_text(json.dumps(rows, indent=2, default=float))
