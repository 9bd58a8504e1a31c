"""Third-party bodies benchmark: issue 18's must-show figures in one table.

Each body in ../shared/data/thirdparty/bodies (Khronos' RiggedFigure as
``.glb``, ``.usdz`` and Blender ``.usdc``; GDQuest's mannequin as ``.glb``
and Blender ``.usdc``) with ``ref_male``'s and ``ref_female``'s items, one
row per (body, reference, stage, item):

* ``rig``: the mesh taken as the body (name, vertices) and the pairing of
  the reference's skeleton with the body's (:func:`motion.rig_match.match_skeletons`):
  its confidence and the key roles left unpaired;
* ``fit``: the reference body fitted onto the target
  (:func:`fit.body_fit.fit_character`): p99 of the surface distance both
  ways (area-uniform samples, :func:`fit.measures.chamfer`) and the
  triangles turned over against the pose-aligned start
  (:func:`fit.measures.count_flipped`); issue 18's limits 10 mm and 0;
* ``dress``: the items dressed on the fitted body (:func:`dress.apply.dress`,
  :func:`dress.metrics.dress_report`): new penetrations per item, limit 1 %;
* ``walk`` and ``arms_held_high`` (``--full`` only): ``animate`` of the CMU
  walk and the arms-held-high dance (the first 60 frames at 30 fps, every
  2nd frame measured): the worst frame's separation p95 (items that touch
  the body; limit 15 mm), coverage loss (limit 2 %) and new penetrations
  of each item (:mod:`animate.measures`).

``ok`` is the row against those limits (empty where the stage has none).
Quick: the Blender ``.usdc`` forms, rig, fit and dress; ``--full`` adds
the ``.glb``/``.usdz`` forms and the two clips.

Run alone: ``python3 benchmarks/bench_thirdparty.py [--full]``.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import BVH_DIR, DATA, DEFAULT_OUT, USD_DIR, clip_end, format_table  # noqa: E402

BODY_DIR = DATA / "thirdparty" / "bodies"
REFS = ("ref_male.usda", "ref_female.usda")
CLIPS = {"walk": "cmu_07_01_walk.bvh", "arms_held_high": "cmu_05_12_dance_arms_held_high.bvh"}
#: issue 18's limits
FIT_P99_MM = 10.0
FLIPPED = 0
NEW_PEN_PCT = 1.0
SEPARATION_P95_MM = 15.0
COVERAGE_LOSS_PCT = 2.0
FRAMES = 60


def bodies(full: bool) -> list[Path]:
    """The third-party body files: the Blender ``.usdc`` forms, and with
    ``full`` the ``.glb``/``.usdz`` ones too."""
    found = sorted(p for p in BODY_DIR.glob("*") if p.suffix.lower() in (".usdc", ".usdz", ".glb", ".gltf"))
    return found if full else [p for p in found if p.suffix.lower() == ".usdc"]


def _rig_row(ref, target) -> dict:
    from wearfit_usd.motion.rig_match import match_skeletons
    s, t = ref.skeleton, target.skeleton
    m = match_skeletons(s.joint_names, s.parents, s.rest_world()[:, 3, :3],
                        t.joint_names, t.parents, t.rest_world()[:, 3, :3])
    return {"stage": "rig", "item": target.body.name, "body_verts": int(target.body.n_points),
            "paired_joints": len(m.mapping.pairs), "confidence": round(float(m.confidence), 3),
            "unpaired_key_roles": m.unpaired_text() or "-", "ok": m.ok}


def _fit_row(ref, target):
    from wearfit_usd.fit.body_fit import fit_character
    from wearfit_usd.fit.measures import chamfer, count_flipped
    t0 = time.perf_counter()
    res = fit_character(ref, target)
    sec = time.perf_counter() - t0
    c = chamfer(res.points, ref.body.faces, target.body.points, target.body.faces)
    flipped = int(count_flipped(res.posed_points, res.points, ref.body.faces))
    fwd, bwd = c["fit_to_target_surface_p99_mm"], c["target_to_fit_surface_p99_mm"]
    row = {"stage": "fit", "item": "body", "fit_to_target_p99_mm": round(fwd, 2),
           "target_to_fit_p99_mm": round(bwd, 2), "flipped": flipped, "seconds": round(sec, 1),
           "ok": max(fwd, bwd) <= FIT_P99_MM and flipped <= FLIPPED}
    return row, res.points


def _dress_rows(ref, target, fitted) -> list[dict]:
    from wearfit_usd.dress.apply import dress
    from wearfit_usd.dress.metrics import dress_report
    t0 = time.perf_counter()
    res = dress(ref, target, body_points=fitted)
    sec = time.perf_counter() - t0
    return [{"stage": "dress", "item": r["item"], "new_pen_pct": round(r["new_pen_pct"], 2),
             "seconds": round(sec, 1), "ok": r["new_pen_pct"] <= NEW_PEN_PCT}
            for r in dress_report(ref, target, res)]


def _motion_rows(ref, target, stage: str, clip: Path, out_dir: Path) -> list[dict]:
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.io.bvh import read_bvh
    motion = read_bvh(clip)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(dir=out_dir) as tmp:
        rep = animate(ref, target, motion, Path(tmp) / "shot.usdc",
                      AnimateOptions(start=1, end=clip_end(motion, FRAMES), measure_every=2, items="points"))
    sec = time.perf_counter() - t0
    rows = []
    for item, worst in rep.motion_worst.items():
        v = {k: worst[k]["value"] if worst.get(k) else None
             for k in ("separation_p95_mm", "coverage_loss_pct", "new_pen_pct")}
        # None: not measured for the item (no vertex touching the body, no body it covers)
        sep, cov = v["separation_p95_mm"], v["coverage_loss_pct"]
        ok = (sep is None or sep <= SEPARATION_P95_MM) and (cov is None or cov <= COVERAGE_LOSS_PCT)
        rows.append({"stage": stage, "item": item,
                     **{k: None if x is None else round(x, 2) for k, x in v.items()},
                     "seconds": round(sec, 1), "ok": ok})
    return rows


def run(full: bool, out_dir: Path) -> list[dict]:
    from wearfit_usd.io.usd import read_character
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    refs = {Path(r).stem: read_character(USD_DIR / r) for r in REFS}
    rows = []
    for path in bodies(full):
        target = read_character(path)
        for ref_name, ref in refs.items():
            head = {"body": path.name, "ref": ref_name}
            rows.append({**head, **_rig_row(ref, target)})
            fit_row, fitted = _fit_row(ref, target)
            rows.append({**head, **fit_row})
            rows += [{**head, **r} for r in _dress_rows(ref, target, fitted)]
            if full:
                for stage, clip in CLIPS.items():
                    if (BVH_DIR / clip).exists():
                        rows += [{**head, **r} for r in _motion_rows(ref, target, stage, BVH_DIR / clip, out_dir)]
    return rows


def summary(rows: list[dict]) -> dict:
    """Rows within issue 18's limits, per stage: {stage: (ok, rows)}."""
    out: dict = {}
    for r in rows:
        ok, n = out.get(r["stage"], (0, 0))
        out[r["stage"]] = (ok + bool(r["ok"]), n + 1)
    return out


if __name__ == "__main__":
    result = run("--full" in sys.argv, DEFAULT_OUT)
    print(format_table(result))
    print({k: f"{a} of {b}" for k, (a, b) in summary(result).items()})
