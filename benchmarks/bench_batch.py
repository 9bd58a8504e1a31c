"""`wearfit batch` over the dev set: 2 references x all 10 dev targets x 3
clips (15 output frames each), products fit, dress, animate, preview, plus a
job on a broken body and one with a missing clip (they must fail alone).

Measures, in one run on the same machine (its load average is recorded
beside every figure: the machine may be shared, so compare ratios):

- jobs per minute with 2 and 1 local worker processes and with a real
  ``dask scheduler`` + two ``dask worker`` processes started here, and the
  same work as `wearfit` commands run one after another;
- that the three batch runs wrote bitwise the same USD points;
- the dressing plans built, the highest peak memory of a job;
- the re-run with --resume after touching one target (same bytes) and after
  changing its bytes: the jobs recomputed are counted from report.json.

Run alone: ``python3 benchmarks/bench_batch.py WORKDIR [--frames-end N]``
(the dev inputs are copied into WORKDIR/inputs so one of them can be changed).
Prints one JSON summary and writes it to WORKDIR/bench_batch.json.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("WEARFIT_DATA", REPO.parent / "shared" / "data"))
TARGETS = ["female_heavy", "female_heavy_remeshed", "female_short", "female_thin", "female_uncommon_yup",
           "male_heavy", "male_muscular_heavy", "male_muscular_posed", "male_tall", "male_cmu_rig"]
REFERENCES = ["ref_female.usda", "ref_male.usda"]
CLIPS = ["cmu_07_01_walk.bvh", "cmu_09_11_run.bvh", "cmu_02_05_punch_strike.bvh"]
PRODUCTS = ["fit", "dress", "animate", "preview"]
TOUCHED = "body_female_thin.usdc"


def dev_job_file(work: Path, end: int) -> Path:
    """Copy the dev inputs into ``work/inputs`` and write ``work/inputs/dev.json``
    (relative paths): the cross product as explicit rows, then the two bad jobs."""
    inp = work / "inputs"
    inp.mkdir(parents=True, exist_ok=True)
    for name in REFERENCES + [f"body_{t}.usdc" for t in TARGETS]:
        shutil.copyfile(DATA / "usd" / name, inp / name)
    for clip in CLIPS:
        shutil.copyfile(DATA / "bvh" / clip, inp / clip)
    (inp / "broken_body.usdc").write_bytes(b"PXR-USDC this is not a crate file")
    clips = [{"path": c, "start": 1, "end": end} for c in CLIPS]
    rows = [{"reference": r, "target": f"body_{t}.usdc", "clips": clips, "products": PRODUCTS}
            for r in REFERENCES for t in TARGETS]
    rows += [{"reference": "ref_female.usda", "target": "broken_body.usdc", "products": ["dress"]},
             {"reference": "ref_male.usda", "target": "body_male_tall.usdc",
              "clip": {"path": "missing_clip.bvh", "start": 1, "end": end}, "products": ["animate"]}]
    (inp / "dev.json").write_text(json.dumps({"jobs": rows}, indent=1))
    return inp / "dev.json"


def load() -> float:
    return round(os.getloadavg()[0], 2)


def wearfit(*args, env=None) -> float:
    env = dict(os.environ, PYTHONPATH=str(REPO), **(env or {}))
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "wearfit_usd", *args], check=False, env=env,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def batch(job: Path, out: Path, *extra) -> dict:
    l0 = load()
    wall = wearfit("batch", "-q", str(job), "-o", str(out), *extra)
    rep = json.loads((out / "report.json").read_text())
    s = rep["summary"]
    return dict(s, command_seconds=round(wall, 2), load_before=l0, load_after=load(),
                contact_sheets=len(rep["contact_sheets"]))


def with_cluster(work: Path, fn):
    """Run ``fn(address)`` with a `dask scheduler` and two `dask worker`
    processes on a free loopback port (stopped afterwards)."""
    from distributed import Client
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    logs = open(work / "dask.log", "w")
    procs = [subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port",
                               str(port), "--no-dashboard"], env=env, stdout=logs, stderr=logs)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nthreads", "1",
                                           "--no-dashboard"], env=env, cwd=work, stdout=logs, stderr=logs))
        with Client(address, timeout="60s") as c:
            c.wait_for_workers(2, timeout=120)
        return fn(address)
    finally:
        for p in procs[1:] + procs[:1]:
            p.terminate()
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        logs.close()


def pairs_mixed() -> list[tuple[str, str]]:
    """Every (reference, target) pair, alternating references and mixing
    same-sex, cross-sex and remeshed targets (a prefix is a fair sample)."""
    order = ["female_thin", "male_heavy", "female_heavy_remeshed", "female_short", "male_tall",
             "male_muscular_posed", "female_uncommon_yup", "male_cmu_rig", "male_muscular_heavy", "female_heavy"]
    order = [t for t in order if t in TARGETS]
    return [(REFERENCES[(i + k) % 2], t) for k in range(2) for i, t in enumerate(order)]


def sequential(inp: Path, out: Path, end: int, cap: float | None = None) -> tuple[float, int]:
    """The same work as `wearfit` commands one after another, whole pairs at
    a time (:func:`pairs_mixed`), stopping after ``cap`` seconds when given;
    with the figures the batch records (dress and shot ``--report``, the shot
    measured every 5th frame as the batch does). Returns (seconds, commands run)."""
    out.mkdir(parents=True, exist_ok=True)
    t, n = 0.0, 0
    for ref, tgt in pairs_mixed():
        if cap is not None and t > cap:
            break
        r, b = str(inp / ref), str(inp / f"body_{tgt}.usdc")
        name = f"{Path(ref).stem}__{tgt}"
        t += wearfit("fit", "-q", r, b, "-o", str(out / f"fit_{name}.usd"))
        t += wearfit("dress", "-q", r, b, "-o", str(out / f"dress_{name}.usd"),
                     "--report", str(out / f"dress_{name}.json"))
        for clip in CLIPS:
            shot = f"anim_{name}_{Path(clip).stem}"
            t += wearfit("animate", "-q", r, b, str(inp / clip), "--start", "1", "--end", str(end),
                         "-o", str(out / f"{shot}.usd"), "--report", str(out / f"{shot}.json"), "--measure-every", "5")
        t += wearfit("render", "-q", str(out / f"dress_{name}.usd"), "-o", str(out / f"png_{name}"),
                     "--camera", "front", "--size", "320x400")
        n += 6
    return t, n


def usd_points(path) -> dict:
    """Every point-array value of a stage at every time sample, as bytes."""
    import numpy as np
    from pxr import Usd
    stage = Usd.Stage.Open(str(path))
    out = {}
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            if "GfVec3f" in attr.GetTypeName().cppTypeName:
                for t in attr.GetTimeSamples() or [Usd.TimeCode.Default()]:
                    v = attr.Get(t)
                    if v is not None:
                        out[str(prim.GetPath()), attr.GetName(), str(t)] = np.asarray(v).tobytes()
    return out


def compare(a: Path, b: Path) -> dict:
    """USD outputs of two batch runs of the same job file: how many, how many differ."""
    ra = {j["id"]: j for j in json.loads((a / "report.json").read_text())["jobs"]}
    rb = {j["id"]: j for j in json.loads((b / "report.json").read_text())["jobs"]}
    same = differ = 0
    for i, j in ra.items():
        if j["status"] != "ok" or j["product"] == "preview":
            continue
        if rb[i]["status"] == "ok" and usd_points(j["output"]) == usd_points(rb[i]["output"]):
            same += 1
        else:
            differ += 1
    return {"usd_outputs_bitwise_equal": same, "differ": differ,
            "same_status": all(ra[i]["status"] == rb[i]["status"] for i in ra)}


def change_bytes(path: Path) -> None:
    """Re-save a USD stage with one more line of documentation: other bytes, same geometry."""
    from pxr import Usd
    stage = Usd.Stage.Open(str(path))
    layer = stage.GetRootLayer()
    layer.documentation = (layer.documentation or "") + " touched by bench_batch"
    layer.Save()


def main(work: Path, end: int = 61, skip_sequential: bool = False, sequential_cap: float | None = None) -> dict:
    job = dev_job_file(work, end)
    res = {"jobs_file": str(job), "clip_range": [1, end], "cores": os.cpu_count()}
    res["local_2_workers"] = batch(job, work / "out2", "--workers", "2")
    res["local_1_worker"] = batch(job, work / "out1", "--workers", "1")
    res["scheduler_2_workers"] = with_cluster(work, lambda a: batch(job, work / "outS", "--scheduler", a))
    if not skip_sequential:
        l0 = load()
        seq, m = sequential(job.parent, work / "seq", end, sequential_cap)
        res["sequential_commands"] = {"commands": m, "seconds": round(seq, 2),
                                      "jobs_per_minute": round(60 * m / seq, 2), "load_before": l0,
                                      "load_after": load()}
        for k in ("local_1_worker", "local_2_workers", "scheduler_2_workers"):
            res[k]["speedup_over_sequential"] = round(res[k]["jobs_per_minute"] / res["sequential_commands"]
                                                      ["jobs_per_minute"], 2)
    res["local_2_vs_scheduler"] = compare(work / "out2", work / "outS")
    res["local_2_vs_local_1"] = compare(work / "out2", work / "out1")
    rep = json.loads((work / "out2" / "report.json").read_text())
    res["failures"] = {r["id"]: r["error"] for r in rep["jobs"] if r["status"] == "failed"}
    os.utime(job.parent / TOUCHED)  # a touch alone: same bytes
    res["rerun_after_touch"] = batch(job, work / "out2", "--workers", "2", "--resume")
    change_bytes(job.parent / TOUCHED)
    res["rerun_after_byte_change"] = batch(job, work / "out2", "--workers", "2", "--resume")
    rep = json.loads((work / "out2" / "report.json").read_text())
    recomputed = sorted(r["id"] for r in rep["jobs"] if r.get("cache") == "miss" and r["status"] == "ok")
    res["recomputed_jobs"] = recomputed
    res["recomputed_only_the_changed_target"] = all(f"__{Path(TOUCHED).stem}" in i for i in recomputed)
    return res


def run(full: bool, out_dir: Path) -> list[dict]:
    """The `python3 -m benchmarks` stage: one row per run (quick: 5 output
    frames per clip and no sequential commands; --full: 15 frames and them)."""
    work = Path(out_dir) / "batch"
    res = main(work, 61 if full else 21, skip_sequential=not full)
    (Path(out_dir) / "batch_details.json").write_text(json.dumps(res, indent=1))
    rows = []
    for k in ("local_2_workers", "local_1_worker", "scheduler_2_workers", "rerun_after_touch",
              "rerun_after_byte_change"):
        r = res[k]
        rows.append({"run": k, "jobs": r["jobs"], "computed": r["computed"], "failed": r["failed"],
                     "wall_s": r["command_seconds"], "jobs_per_min": r["jobs_per_minute"],
                     "plans_built": r["plans_built"], "peak_mb": r["max_peak_rss_mb"], "load": r["load_before"]})
    if "sequential_commands" in res:
        r = res["sequential_commands"]
        rows.append({"run": "sequential_commands", "jobs": r["commands"], "computed": r["commands"], "failed": 0,
                     "wall_s": r["seconds"], "jobs_per_min": r["jobs_per_minute"], "plans_built": None,
                     "peak_mb": None, "load": r["load_before"]})
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("work", nargs="?", default="/tmp/bench_batch")
    ap.add_argument("--end", type=int, default=61, help="last clip frame (exclusive; 120 fps clips, 30 fps out)")
    ap.add_argument("--skip-sequential", action="store_true")
    ap.add_argument("--sequential-cap", type=float, default=None, metavar="SECONDS",
                    help="stop the one-after-another commands after this long (whole pairs; jobs/min compares)")
    a = ap.parse_args()
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    out = main(work, a.end, a.skip_sequential, a.sequential_cap)
    (work / "bench_batch.json").write_text(json.dumps(out, indent=1))
    print(json.dumps(out, indent=1))
