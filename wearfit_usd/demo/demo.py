"""`wearfit demo`: the whole pipeline on the project's own samples.

Nothing is downloaded and the shared data set is not needed:

1. make the sample set (:mod:`wearfit_usd.demo.samples`): a rigged reference body
   wearing ten items, the same body wearing the loose garments (``ref_loose``:
   a long A-line dress, long hair, shoes; the other garment outfits of
   :data:`~wearfit_usd.demo.samples.GARMENT_SETS` are left out, to keep the
   demo quick) and four target bodies (three with the reference's topology,
   one remeshed);
2. dress every target (body fit + binding + redress) with the reference's
   items and with ``ref_loose``'s, and measure the fit;
3. animate shots (a packaged BVH clip on a dressed target, per shot; one of
   them wears the loose garments);
4. render previews (stills line-up: the reference's items on the top row,
   the loose garments below; frames, contact sheet, GIF, MP4);
5. write ``report.json`` and ``report.md``.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..animate.try_on import AnimateOptions, animate
from ..dress.apply import dress
from ..dress.metrics import dress_report
from ..io.bvh import read_bvh
from ..io.usd import read_character, write_character
from ..io.usd_validate import validate_stage
from ..progress import info
from .samples import motion_path, write_sample_set

#: (clip, target[, reference]) animated by default: one same-topology target
#: and the remeshed one, so both body-fitting paths run, and the loose
#: garments (reference ``ref_loose``; default: ``reference``) walking.
DEFAULT_SHOTS = [("walk", "short_heavy"), ("arm_raise", "curvy_remeshed"),
                 ("walk", "tall_thin", "ref_loose")]
#: the garment reference dressed on every target and shown in the line-up's second row
LOOSE_REFERENCE = "ref_loose"


def _lineup(rows: list[list[Path]], size=(300, 450)) -> np.ndarray:
    """One front still per stage, side by side, one row per list
    (H * len(rows), W * len(row), 3) uint8."""
    from ..render import render_frames
    return np.concatenate([np.concatenate([render_frames(p, size=size, camera="front", show_progress=False)[0]
                                           for p in paths], axis=1) for paths in rows], axis=0)


def _dress_targets(reference, samples: dict, out_dir: Path, fitted: dict | None = None) -> tuple[dict, dict]:
    """Dress every target of the sample set with ``reference``'s items into
    ``out_dir/<target>.usda``. Returns (report entries, dressed paths) keyed
    by target name.

    fitted: {target name: (reference body points (N, 3), fitted body points
        (N, 3))} from an earlier call; reused when ``reference``'s body is
        the same (the references share one body: the fit is done once).
        Filled in with this call's fits."""
    fitted = {} if fitted is None else fitted
    entries, dressed = {}, {}
    for key, path in samples.items():
        if not key.startswith("target_"):
            continue
        name = key[len("target_"):]
        t0 = time.perf_counter()
        target = read_character(path)
        known = fitted.get(name)
        same_body = known is not None and np.array_equal(known[0], reference.body.points)
        res = dress(reference, target, body_points=known[1] if same_body else None)
        fitted.setdefault(name, (reference.body.points, res.body_points))
        dst = out_dir / f"{name}.usda"
        write_character(dst, target, items=res.items)
        dt = time.perf_counter() - t0
        rows = dress_report(reference, target, res)
        entries[name] = {
            "seconds": dt, "same_topology": target.body.n_points == reference.body.n_points,
            "body_vertices": target.body.n_points,
            "worst_new_pen_pct": max(r["new_pen_pct"] for r in rows),
            "worst_clear_med_mm": max(r["clear_med_mm"] for r in rows),
            "worst_clear_p95_mm": max(r["clear_p95_mm"] for r in rows),
            "items": rows, "valid_usd": validate_stage(dst) == [], "file": str(dst)}
        dressed[name] = dst
        info(f"dressed {name}: worst item new penetration "
             f"{entries[name]['worst_new_pen_pct']:.2f} %, clearance change median "
             f"{entries[name]['worst_clear_med_mm']:.2f} mm ({dt:.1f} s)")
    return entries, dressed


def run_demo(out_dir, shots=None, render: bool = True, size=(480, 360), gif: bool = True,
             mp4: bool = True) -> dict:
    """Run the demo into ``out_dir``; returns the report (also written as
    ``report.json`` / ``report.md``).

    The renderer (pyrender/OpenGL) and the media writers are imported only
    when ``render`` asks for them: they are heavy and may be missing.
    """

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    shots = DEFAULT_SHOTS if shots is None else shots
    t_all = time.perf_counter()
    report: dict = {"timings_s": {}, "dress": {}, "dress_loose": {}, "shots": {}, "files": {}}

    t0 = time.perf_counter()
    info("making the sample bodies and items ...")
    samples = write_sample_set(out / "samples", garment_sets=[LOOSE_REFERENCE])
    report["timings_s"]["samples"] = time.perf_counter() - t0
    report["files"]["samples"] = {k: str(v) for k, v in samples.items()}
    references = {"reference": read_character(samples["reference"])}
    reference = references["reference"]
    fitted: dict = {}
    report["dress"], dressed = _dress_targets(reference, samples, out / "dressed", fitted)
    info(f"dressing the loose garments ({LOOSE_REFERENCE}) ...")
    references[LOOSE_REFERENCE] = read_character(samples[LOOSE_REFERENCE])
    report["dress_loose"], dressed_loose = _dress_targets(references[LOOSE_REFERENCE], samples,
                                                          out / f"dressed_{LOOSE_REFERENCE}", fitted)

    for clip, target_name, *ref_key in shots:
        t0 = time.perf_counter()
        ref_name = ref_key[0] if ref_key else "reference"
        if ref_name not in references:
            references[ref_name] = read_character(samples[ref_name])
        target = read_character(samples[f"target_{target_name}"])
        motion = read_bvh(motion_path(clip))
        suffix = "" if ref_name == "reference" else f"_{ref_name}"
        shot = out / f"shot_{clip}_{target_name}{suffix}.usdc"
        rep = animate(references[ref_name], target, motion, shot, AnimateOptions(fps=30, measure_every=2))
        problems = validate_stage(shot)
        entry = {"clip": clip, "target": target_name, "reference": ref_name,
                 "frames": rep.frames, "fps": rep.fps,
                 "clip_frames": motion.n_frames, "valid_usd": problems == [],
                 "validation_messages": problems,
                 "worst_frame_new_pen_pct": 100 * rep.worst_frame_penetration,
                 "mean_new_pen_pct": 100 * float(np.mean(rep.per_frame_penetration)),
                 "timings_s": {k: v for k, v in rep.timings.items() if not isinstance(v, dict)},
                 "file": str(shot)}
        if render:
            from ..render import render_to_dir
            prev = render_to_dir(shot, out / "preview" / shot.stem, size=size, camera="auto",
                                 gif=gif, mp4=mp4, show_progress=False)
            entry["preview"] = {k: str(v) for k, v in prev.items() if k in ("gif", "mp4", "contact_sheet")}
            entry["preview_frames"] = prev["n_frames"]
        entry["seconds"] = time.perf_counter() - t0
        report["shots"][shot.stem] = entry
        info(f"animated {clip} on {target_name} ({ref_name}): {rep.frames} frames, worst frame new penetration "
             f"{entry['worst_frame_new_pen_pct']:.2f} % ({entry['seconds']:.1f} s)")

    if render:
        t0 = time.perf_counter()
        from ..render.media import write_png
        image = _lineup([[samples["reference"]] + [dressed[n] for n in dressed],
                         [samples[LOOSE_REFERENCE]] + [dressed_loose[n] for n in dressed]])
        report["files"]["lineup"] = str(write_png(image, out / "lineup.png"))
        report["timings_s"]["lineup"] = time.perf_counter() - t0
    report["timings_s"]["total"] = time.perf_counter() - t_all
    (out / "report.json").write_text(json.dumps(report, indent=2, default=float))
    (out / "report.md").write_text(markdown(report))
    return report


def markdown(report: dict) -> str:
    """A short human-readable summary of a demo report."""
    lines = ["# wearfit demo report", "",
             f"Total time: {report['timings_s']['total']:.1f} s.", ""]
    if "lineup" in report["files"]:
        lines += ["![reference and dressed targets; below: the loose garments](lineup.png)", ""]
    for key, title in (("dress", "reference items"), ("dress_loose", f"{LOOSE_REFERENCE}'s loose garments")):
        if not report.get(key):
            continue
        lines += [f"## Dressing ({title} on each target)", "",
                  "| target | same topology | worst new penetration % | worst clearance change median mm "
                  "| worst p95 mm | seconds |", "|---|---|---|---|---|---|"]
        for name, d in report[key].items():
            lines.append(f"| {name} | {d['same_topology']} | {d['worst_new_pen_pct']:.3f} | "
                         f"{d['worst_clear_med_mm']:.2f} | {d['worst_clear_p95_mm']:.2f} | {d['seconds']:.1f} |")
        lines.append("")
    lines += ["## Shots", "", "| shot | frames | fps | valid USD | worst-frame new penetration % "
              "| binding eval frames/s | seconds |", "|---|---|---|---|---|---|---|"]
    for name, s in report["shots"].items():
        lines.append(f"| {name} | {s['frames']} | {s['fps']:g} | {s['valid_usd']} | "
                     f"{s['worst_frame_new_pen_pct']:.3f} | {s['timings_s']['evaluate_fps']:.0f} | "
                     f"{s['seconds']:.1f} |")
        if "preview" in s:
            lines.append("")
            lines.append(f"![{name}](preview/{name}/contact_sheet.png)")
    return "\n".join(lines) + "\n"
