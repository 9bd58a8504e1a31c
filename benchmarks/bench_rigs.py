"""Rig benchmark: every clip on every rig (issue 18's "any clip" figures).

Each BVH clip (CMU-family in ../shared/data/bvh and the third-party ones in
../shared/data/thirdparty/bvh: Mixamo names, inches at 120 fps) retargeted
onto the bodies of ref_male, ref_female and GDQuest's mannequin with the
floor placement `wearfit animate` uses: the unit read, the key joints
paired and the pairing's confidence, the lowest body point above the rest
floor at the first frame and its median over the clip, the hips' travel
against the clip's own scaled by leg length (:mod:`wearfit_usd.motion.clip_check`),
and ``ok`` against issue 18's limits (3 cm, 5 cm, 10 %). Quick: the first 40
evaluated frames spread over each clip, the same as full (cheap either way).

Run alone: ``python3 benchmarks/bench_rigs.py``.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import BVH_DIR, DATA, DEFAULT_OUT, USD_DIR, format_table  # noqa: E402

BODIES = {"ref_male": USD_DIR / "ref_male.usda", "ref_female": USD_DIR / "ref_female.usda",
          "mannequin": DATA / "thirdparty" / "bodies" / "mannequiny_idle_blender.usdc"}


def clips() -> list[Path]:
    return sorted(BVH_DIR.glob("*.bvh")) + sorted((DATA / "thirdparty" / "bvh").glob("*.bvh"))


def run(full: bool, out_dir: Path) -> list[dict]:
    from wearfit_usd.io.usd import read_character
    from wearfit_usd.motion.clip_check import clip_on_body, within_limits
    chars = {k: read_character(v) for k, v in BODIES.items() if v.exists()}
    rows = []
    for clip in clips():
        for name, char in chars.items():
            t0 = time.perf_counter()
            r = clip_on_body(clip, char, max_eval=80 if full else 40)
            rows.append({"clip": clip.stem, "body": name, "units": r["units"], "mapped": bool(r["mapped"]),
                         "confidence": round(float(r["confidence"]), 3),
                         "frame0_cm": round(r["frame0_cm"], 2), "median_cm": round(r["median_cm"], 2),
                         "travel_m": round(r["travel_m"], 3),
                         "clip_travel_scaled_m": round(r["clip_travel_scaled_m"], 3),
                         "travel_err_pct": round(100 * r["travel_err"], 2), "shift_cm": round(r["shift_cm"], 1),
                         "ok": within_limits(r), "seconds": round(time.perf_counter() - t0, 2)})
    return rows


if __name__ == "__main__":
    print(format_table(run("--full" in sys.argv, DEFAULT_OUT)))
