"""`wearfit batch` over the dev set: 2 references x their 5 dev targets x 3
clips (30 output frames each), products fit, dress, animate, preview.

Measures jobs per minute with 1 and 2 local worker processes, the same
`wearfit` commands run one after another, and the re-run with --resume after
one target's bytes changed (the jobs recomputed are counted from the cache
misses in report.json). Prints one JSON summary.

Run alone: ``python3 benchmarks/bench_batch.py WORKDIR`` (the dev inputs are
copied into WORKDIR/inputs so one of them can be changed).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("WEARFIT_DATA", REPO.parent / "shared" / "data"))
FEMALE = ["female_heavy", "female_heavy_remeshed", "female_short", "female_thin", "female_uncommon_yup"]
MALE = ["male_heavy", "male_muscular_heavy", "male_muscular_posed", "male_tall", "male_cmu_rig"]
CLIPS = [("cmu_07_01_walk.bvh", 1, 121), ("cmu_09_11_run.bvh", 1, 121), ("cmu_02_05_punch_strike.bvh", 1, 121)]
PRODUCTS = ["fit", "dress", "animate", "preview"]


def dev_job_file(work: Path) -> Path:
    """Copy the dev inputs into ``work/inputs`` and write ``work/inputs/dev.json`` (relative paths)."""
    inp = work / "inputs"
    inp.mkdir(parents=True, exist_ok=True)
    for name in ["ref_female.usda", "ref_male.usda"] + [f"body_{t}.usdc" for t in FEMALE + MALE]:
        shutil.copyfile(DATA / "usd" / name, inp / name)
    for clip, _, _ in CLIPS:
        shutil.copyfile(DATA / "bvh" / clip, inp / clip)
    job = {"references": [{"path": "ref_female.usda", "targets": [f"body_{t}.usdc" for t in FEMALE]},
                          {"path": "ref_male.usda", "targets": [f"body_{t}.usdc" for t in MALE]}],
           "clips": [{"path": c, "start": s, "end": e} for c, s, e in CLIPS],
           "products": PRODUCTS}
    (inp / "dev.json").write_text(json.dumps(job, indent=1))
    return inp / "dev.json"


def wearfit(*args) -> float:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "wearfit_usd", *args], check=False, env=env,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def batch(job: Path, out: Path, *extra) -> dict:
    wall = wearfit("batch", "-q", str(job), "-o", str(out), *extra)
    s = json.loads((out / "report.json").read_text())["summary"]
    return dict(s, command_seconds=round(wall, 2))


def sequential(inp: Path, out: Path) -> float:
    """The same work as `wearfit` commands one after another."""
    out.mkdir(parents=True, exist_ok=True)
    t = 0.0
    for ref, targets in (("ref_female.usda", FEMALE), ("ref_male.usda", MALE)):
        for tgt in targets:
            r, b = str(inp / ref), str(inp / f"body_{tgt}.usdc")
            name = f"{Path(ref).stem}__{tgt}"
            t += wearfit("fit", "-q", r, b, "-o", str(out / f"fit_{name}.usd"))
            t += wearfit("dress", "-q", r, b, "-o", str(out / f"dress_{name}.usd"))
            for clip, s, e in CLIPS:
                t += wearfit("animate", "-q", r, b, str(inp / clip), "--start", str(s), "--end", str(e),
                             "-o", str(out / f"anim_{name}_{Path(clip).stem}.usd"))
            t += wearfit("render", "-q", str(out / f"dress_{name}.usd"), "-o", str(out / f"png_{name}"),
                         "--camera", "front", "--size", "320x400")
    return t


def change_bytes(path: Path) -> None:
    """Re-save a USD stage with one more line of documentation: other bytes, same geometry."""
    from pxr import Usd
    stage = Usd.Stage.Open(str(path))
    layer = stage.GetRootLayer()
    layer.documentation = (layer.documentation or "") + " touched by bench_batch"
    layer.Save()


def main(work: Path) -> dict:
    job = dev_job_file(work)
    res = {"jobs_file": str(job)}
    res["local_2_workers"] = batch(job, work / "out2", "--workers", "2")
    res["local_1_worker"] = batch(job, work / "out1", "--workers", "1")
    n = res["local_2_workers"]["jobs"]
    seq = sequential(job.parent, work / "seq")
    res["sequential_commands"] = {"seconds": round(seq, 2), "jobs_per_minute": round(60 * n / seq, 2)}
    for k in ("local_1_worker", "local_2_workers"):
        res[k]["speedup_over_sequential"] = round(seq / res[k]["command_seconds"], 2)
    os.utime(job.parent / "body_female_thin.usdc")  # a touch alone: same bytes
    res["rerun_after_touch"] = batch(job, work / "out2", "--workers", "2", "--resume")
    change_bytes(job.parent / "body_female_thin.usdc")
    res["rerun_after_byte_change"] = batch(job, work / "out2", "--workers", "2", "--resume")
    rep = json.loads((work / "out2" / "report.json").read_text())
    res["recomputed_jobs"] = sorted(r["id"] for r in rep["jobs"] if r.get("cache") == "miss")
    return res


if __name__ == "__main__":
    work = Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/bench_batch")
    print(json.dumps(main(work), indent=1))
