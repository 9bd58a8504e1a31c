"""`wearfit batch`: job files, cache keys, real runs on a local Dask cluster
and on a scheduler with workers started as separate processes."""
from __future__ import annotations

import importlib.util
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import BVH_DIR, REPO, USD_DIR
from tests.usd_values import usd_points
from wearfit_usd.batch.cache import Cache, file_digest, result_key
from wearfit_usd.batch.graph import assign_owners
from wearfit_usd.batch.jobs import Clip, Job, load_jobs
from wearfit_usd.errors import InputError

# ---------------------------------------------------------------- job files


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_json_cross_product_relative_paths(tmp_path):
    job = _write(tmp_path, "jobs.json", json.dumps({
        "references": ["ref_a.usda", "/abs/ref_b.usda"], "targets": ["bodies/b1.usdc", "b2.usdc"],
        "clips": [{"path": "walk.bvh", "start": 1, "end": 61}, "run.bvh"], "products": ["dress", "animate"]}))
    js = load_jobs(job)
    assert len(js.jobs) == 2 * 2 * (1 + 2)
    first = js.jobs[0]
    assert first == Job("dress", tmp_path / "ref_a.usda", tmp_path / "bodies" / "b1.usdc")
    anim = [j for j in js.jobs if j.product == "animate"]
    assert anim[0].clip == Clip(tmp_path / "walk.bvh", 1, 61)
    assert anim[1].clip == Clip(tmp_path / "run.bvh", None, None)  # start "auto" (motion.clip_start)
    assert anim[1].id == "animate/ref_a__b1__run_auto-"
    assert {j.reference for j in js.jobs} == {tmp_path / "ref_a.usda", Path("/abs/ref_b.usda")}
    assert anim[0].id == "animate/ref_a__b1__walk_1-61"
    assert js.options["format"] == "usd"


def test_yaml_per_reference_targets_and_explicit_rows(tmp_path):
    job = _write(tmp_path, "jobs.yaml", """
references:
  - path: ref_f.usda
    targets: [f1.usdc, f2.usdc]
  - path: ref_m.usda
    targets: [m1.usdc]
products: [fit]
options: {format: usdc, k: 4}
""")
    js = load_jobs(job)
    assert [(j.reference.name, j.target.name) for j in js.jobs] == \
        [("ref_f.usda", "f1.usdc"), ("ref_f.usda", "f2.usdc"), ("ref_m.usda", "m1.usdc")]
    assert js.options["format"] == "usdc" and js.options["k"] == 4
    rows = _write(tmp_path, "rows.yml", """
jobs:
  - {reference: r.usda, target: t.usdc, clip: {path: c.bvh, start: 2, end: 12}, products: [animate, dress]}
  - {reference: r.usda, target: u.usdc}
""")
    js = load_jobs(rows)
    assert [j.id for j in js.jobs] == ["animate/r__t__c_2-12", "dress/r__t", "dress/r__u"]


def test_csv_rows(tmp_path):
    job = _write(tmp_path, "jobs.csv", "reference,target,clip,start,end,products\n"
                                       "r.usda,t.usdc,c.bvh,1,31,animate;dress\n"
                                       "r.usda,u.usdc,,,,fit\n")
    js = load_jobs(job)
    assert [j.id for j in js.jobs] == ["animate/r__t__c_1-31", "dress/r__t", "fit/r__u"]
    assert js.jobs[0].clip.path == tmp_path / "c.bvh"


@pytest.mark.parametrize("name,text,problem", [
    ("bad.json", '{"references": ["a.usda"], "targets": ["b.usdc"],,}', "invalid JSON"),
    ("bad.yaml", "references: [a.usda\ntargets: b", "invalid YAML"),
    ("bad.json", '{"references": ["a.usda"], "targets": ["b.usdc"], "products": ["gltf"]}', "unknown products"),
    ("bad.json", '{"references": ["a.usda"], "targets": ["b.usdc"], "products": ["animate"]}',
     "needs at least one clip"),
    ("bad.json", '{"references": [], "targets": ["b.usdc"]}', "'references' must be a non-empty list"),
    ("bad.json", '{"references": ["a.usda"]}', "no targets"),
    ("bad.json", '{"refs": ["a.usda"]}', "unknown keys ['refs']"),
    ("bad.json", '{"references": ["a.usda"], "targets": ["b"], "clips": [{"path": "c.bvh", "start": "x"}]}',
     "clips[0].start must be an integer"),
    ("bad.json", '{"references": ["a.usda"], "targets": ["b"], "clips": [{"path": "c.bvh", "start": 5, "end": 5}]}',
     "is empty"),
    ("bad.json", '{"references": ["a.usda"], "targets": ["b"], "clips": [{"path": "c", "start": "auto", "end": 0}]}',
     "is empty"),
    ("bad.json", '{"references": ["a.usda"], "targets": ["b"], "options": {"format": "obj"}}', "options.format"),
    ("bad.csv", "reference,clip\nr.usda,c.bvh\n", "lacks the columns ['target']"),
    ("bad.txt", "{}", "ends in .json"),
])
def test_job_file_errors_name_file_and_problem(tmp_path, name, text, problem):
    job = _write(tmp_path, name, text)
    with pytest.raises(InputError) as err:
        load_jobs(job)
    assert str(job) in str(err.value)
    assert problem in str(err.value)


def test_missing_job_file(tmp_path):
    with pytest.raises(InputError, match="job file not found"):
        load_jobs(tmp_path / "nope.json")


# ---------------------------------------------------------------- cache keys


def test_cache_keys_follow_input_bytes_and_options(tmp_path):
    a, b = tmp_path / "a.usda", tmp_path / "b.usdc"
    a.write_bytes(b"reference")
    b.write_bytes(b"target")
    k0 = result_key("dress", [file_digest(a), file_digest(b)], {"k": 5})
    assert result_key("dress", [file_digest(a), file_digest(b)], {"k": 5}) == k0
    os.utime(b, (1, 1))  # a touch alone: same bytes, same key
    assert result_key("dress", [file_digest(a), file_digest(b)], {"k": 5}) == k0
    assert result_key("dress", [file_digest(a), file_digest(b)], {"k": 4}) != k0
    assert result_key("fit", [file_digest(a), file_digest(b)], {"k": 5}) != k0
    b.write_bytes(b"target!")
    assert result_key("dress", [file_digest(a), file_digest(b)], {"k": 5}) != k0
    assert result_key("dress", [file_digest(b), file_digest(a)], {"k": 5}) != \
        result_key("dress", [file_digest(a), file_digest(b)], {"k": 5})


def test_cache_lookup_needs_record_and_object(tmp_path):
    c = Cache(tmp_path / ".cache")
    key = "ab" * 32
    assert c.lookup(key) is None
    obj = c.object_path(key, ".usd")
    c.store_record(key, {"object": str(obj)})
    assert c.lookup(key) is None  # a record without its object is no result
    obj.write_bytes(b"x")
    assert c.lookup(key)["object"] == str(obj)


# ---------------------------------------------------------------- plan owners


def _jobs(ref: str, n_dress: int, n_fit: int = 0) -> list[Job]:
    r = Path(ref)
    return ([Job("dress", r, Path(f"t{i}.usdc")) for i in range(n_dress)]
            + [Job("fit", r, Path(f"t{i}.usdc")) for i in range(n_fit)])


def test_each_reference_gets_the_least_loaded_worker():
    jobs = _jobs("a.usda", 6, n_fit=9) + _jobs("b.usda", 4) + _jobs("c.usda", 3)
    owners = assign_owners(jobs, ["w1", "w2"])
    # heaviest first (fit jobs need no plan): a (6) -> w1, b (4) -> w2, c (3) -> w2 (4 < 6)
    assert owners == {Path("a.usda"): ["w1"], Path("b.usda"): ["w2"], Path("c.usda"): ["w2"]}
    two = assign_owners(_jobs("a.usda", 2) + _jobs("b.usda", 2), ["w1", "w2"])
    assert two == {Path("a.usda"): ["w1"], Path("b.usda"): ["w2"]}
    assert assign_owners(jobs, []) == {}


def test_plan_workers_spread_a_reference():
    jobs = _jobs("a.usda", 4) + _jobs("b.usda", 2)
    assert assign_owners(jobs, ["w1", "w2", "w3"], per_reference=2) == \
        {Path("a.usda"): ["w1", "w2"], Path("b.usda"): ["w3", "w1"]}
    assert assign_owners(jobs, ["w1"], per_reference=4) == {Path("a.usda"): ["w1"], Path("b.usda"): ["w1"]}


def test_plan_workers_must_be_positive(tmp_path, capsys):
    from wearfit_usd.cli import main
    job = _write(tmp_path, "jobs.json", '{"references": ["a.usda"], "targets": ["b.usdc"]}')
    assert main(["batch", str(job), "-o", str(tmp_path / "out"), "--plan-workers", "0"]) != 0
    assert "--plan-workers must be >= 1" in capsys.readouterr().err


# ---------------------------------------------------------------- real runs


def _job_file(folder: Path) -> Path:
    """1 reference x 2 targets x 1 clip of 10 frames, plus a broken body and a missing clip."""
    broken = folder / "broken_body.usdc"
    broken.write_bytes(b"PXR-USDC this is not a crate file")
    ref = str(USD_DIR / "ref_female.usda")
    clip = {"path": str(BVH_DIR / "cmu_07_01_walk.bvh"), "start": 1, "end": 41}
    job = {"jobs": [
        {"reference": ref, "target": str(USD_DIR / "body_female_thin.usdc"), "clip": clip,
         "products": ["fit", "dress", "animate", "preview"]},
        {"reference": ref, "target": str(USD_DIR / "body_female_short.usdc"), "clip": clip,
         "products": ["dress", "animate"]},
        {"reference": ref, "target": "broken_body.usdc", "products": ["dress"]},
        {"reference": ref, "target": str(USD_DIR / "body_female_thin.usdc"),
         "clip": {"path": "missing_clip.bvh", "start": 1, "end": 41}, "products": ["animate"]},
    ]}
    path = folder / "jobs.json"
    path.write_text(json.dumps(job))
    return path


def _env(**extra) -> dict:
    return dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""), **extra)


def _wearfit(*args, timeout=600, **env):
    return subprocess.run([sys.executable, "-m", "wearfit_usd", *args], capture_output=True, text=True,
                          env=_env(**env), timeout=timeout)


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    """The job file run on the default local cluster with 2 worker processes."""
    folder = tmp_path_factory.mktemp("batch")
    job = _job_file(folder)
    r = _wearfit("batch", "-q", str(job), "-o", str(folder / "out"), "--workers", "2")
    return job, folder / "out", r


@pytest.mark.slow
def test_local_cluster_run(local_run):
    job, out, r = local_run
    assert r.returncode == 1, r.stderr  # two jobs fail on purpose
    rep = json.loads((out / "report.json").read_text())
    jobs = {j["id"]: j for j in rep["jobs"]}
    ok = [i for i, j in jobs.items() if j["status"] == "ok"]
    assert sorted(ok) == sorted(["fit/ref_female__body_female_thin", "dress/ref_female__body_female_thin",
                                 "animate/ref_female__body_female_thin__cmu_07_01_walk_1-41",
                                 "preview/ref_female__body_female_thin", "dress/ref_female__body_female_short",
                                 "animate/ref_female__body_female_short__cmu_07_01_walk_1-41"])
    for i in ok:
        assert Path(jobs[i]["output"]).is_file()
        assert jobs[i]["cache"] == "miss" and jobs[i]["peak_rss_mb"] > 50 and jobs[i]["seconds"] >= 0
    shot = usd_points(jobs["animate/ref_female__body_female_thin__cmu_07_01_walk_1-41"]["output"])
    assert len({k[2] for k in shot}) >= 10  # 10 frames of time samples
    assert jobs["dress/ref_female__body_female_thin"]["figures"]["items"]
    assert (out / "contact_body_female_thin.png").is_file() and (out / "report.md").is_file()
    assert rep["summary"]["ok"] == 6 and rep["summary"]["failed"] == 2
    if importlib.util.find_spec("bokeh") is None:  # no dashboard without bokeh: no dead link either
        assert rep["cluster"]["dashboard"] is None
    # one reference: its plan built once, by the worker that ran all its dressings and shots
    assert rep["summary"]["plans_built"] == 1
    planned = [jobs[i] for i in ok if jobs[i]["product"] in ("dress", "animate")]
    assert len({j["worker_pid"] for j in planned}) == 1
    assert jobs["dress/ref_female__body_female_thin"]["figures"]["new_penetration_pct"] >= 0
    assert "| peak MiB |" in (out / "report.md").read_text()
    shot_figures = jobs["animate/ref_female__body_female_thin__cmu_07_01_walk_1-41"]["figures"]
    assert shot_figures["motion_worst"] and "stretch p99" in (out / "report.md").read_text()


@pytest.mark.slow
def test_failures_are_isolated_with_their_message(local_run):
    job, out, r = local_run
    rep = json.loads((out / "report.json").read_text())
    jobs = {j["id"]: j for j in rep["jobs"]}
    broken = jobs["dress/ref_female__broken_body"]
    assert broken["status"] == "failed" and "broken_body.usdc" in broken["error"]
    assert broken["error"].startswith("reading target ") and "cannot open as USD" in broken["error"]
    missing = jobs["animate/ref_female__body_female_thin__missing_clip_1-41"]
    assert missing["status"] == "failed" and "missing_clip.bvh: file not found" in missing["error"]
    assert "broken_body" in r.stderr and "missing_clip.bvh" in r.stderr
    assert "## Failures" in (out / "report.md").read_text()


@pytest.mark.slow
def test_resume_reuses_every_result(local_run):
    job, out, _ = local_run
    before = {j["id"]: j for j in json.loads((out / "report.json").read_text())["jobs"]}
    r = _wearfit("batch", "-q", str(job), "-o", str(out), "--workers", "1", "--resume", "--no-previews")
    assert r.returncode == 1, r.stderr
    jobs = {j["id"]: j for j in json.loads((out / "report.json").read_text())["jobs"]}
    hits = sorted(i for i, j in jobs.items() if j["cache"] == "hit")
    assert hits == sorted(i for i, j in before.items() if j["status"] == "ok" and j["product"] != "preview")
    assert all(jobs[i]["status"] == "failed" for i in jobs if i not in hits)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(procs):
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=10)


@pytest.mark.slow
def test_separate_scheduler_and_workers_same_outputs(local_run, tmp_path):
    """`dask scheduler` and two `dask worker` processes started here (on a
    free port, always stopped): the same job file gives bitwise the same USD
    points as on the local cluster."""
    from distributed import Client
    job, local_out, _ = local_run
    address, procs, logs = _start_cluster(tmp_path, _env())
    try:
        with Client(address, timeout="60s") as c:
            worker_pids = set(c.run(os.getpid).values())
        r = _wearfit("batch", "-q", str(job), "-o", str(tmp_path / "out"), "--scheduler", address)
        assert r.returncode == 1, r.stderr
    finally:
        _stop(procs[1:] + procs[:1])
        logs.close()
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert rep["cluster"]["workers"] == 2 and rep["cluster"]["local"] is False
    assert len(worker_pids) == 2 and {j["worker_pid"] for j in rep["jobs"] if j["status"] == "ok"} <= worker_pids
    assert 1 <= rep["summary"]["plans_built"] <= 2  # 2: a plan's tasks stolen by the idle worker
    local = {j["id"]: j for j in json.loads((local_out / "report.json").read_text())["jobs"]}
    compared = 0
    for j in rep["jobs"]:
        if j["id"] not in local:  # the previews, left out by the --resume run
            continue
        assert j["status"] == local[j["id"]]["status"]
        if j["status"] == "ok" and j["product"] != "preview":
            a, b = usd_points(j["output"]), usd_points(local[j["id"]]["output"])
            assert a.keys() == b.keys() and a == b, j["id"]
            compared += 1
    assert compared == 5


@pytest.mark.slow
def test_plan_built_once_and_outputs_equal_the_single_commands(tmp_path):
    """2 workers x 1 reference x 2 targets x 1 clip, dress and animate: the
    reference's plan is built once (every planned task on its worker), and the
    outputs equal `wearfit dress` / `wearfit animate` bitwise (run with one
    BLAS thread, as Dask's workers are)."""
    ref = USD_DIR / "ref_female.usda"
    targets = [USD_DIR / "body_female_thin.usdc", USD_DIR / "body_female_short.usdc"]
    walk = BVH_DIR / "cmu_07_01_walk.bvh"
    job = tmp_path / "jobs.json"
    job.write_text(json.dumps({"references": [str(ref)], "targets": [str(t) for t in targets],
                               "clips": [{"path": str(walk), "start": 1, "end": 41}],
                               "products": ["dress", "animate"]}))
    out = tmp_path / "out"
    r = _wearfit("batch", "-q", str(job), "-o", str(out), "--workers", "2")
    assert r.returncode == 0, r.stderr
    rep = json.loads((out / "report.json").read_text())
    assert rep["cluster"]["workers"] == 2 and rep["summary"]["ok"] == 4
    assert rep["summary"]["plans_built"] == 1
    assert rep["summary"]["plans_built_by_reference"] == {"ref_female.usda": 1}
    assert sum(bool(j["plan_built"]) for j in rep["jobs"]) == 1
    assert len({j["worker_pid"] for j in rep["jobs"]}) == 1
    owners = rep["intermediates"]["owners"]
    assert list(owners) == [str(ref)] and len(owners[str(ref)]) == 1
    assert "dressing plans built 1 (ref_female.usda: 1)" in (out / "report.md").read_text()
    jobs = {j["id"]: j for j in rep["jobs"]}
    single = tmp_path / "single"
    single.mkdir()
    for t in targets:
        name = f"ref_female__{t.stem}"
        d = _wearfit("dress", "-q", str(ref), str(t), "-o", str(single / f"{name}.usd"), OMP_NUM_THREADS="1")
        assert d.returncode == 0, d.stderr
        assert usd_points(single / f"{name}.usd") == usd_points(jobs[f"dress/{name}"]["output"]), name
    t = targets[1]
    name = f"ref_female__{t.stem}"
    a = _wearfit("animate", "-q", str(ref), str(t), str(walk), "--start", "1", "--end", "41",
                 "-o", str(single / f"{name}_walk.usd"), OMP_NUM_THREADS="1")
    assert a.returncode == 0, a.stderr
    shot = usd_points(single / f"{name}_walk.usd")
    assert len({k[2] for k in shot}) >= 10
    assert shot == usd_points(jobs[f"animate/{name}__cmu_07_01_walk_1-41"]["output"])


def _start_cluster(tmp_path, env, nanny=True):
    """`dask scheduler` and two `dask worker` processes on a free loopback
    port; returns (address, [scheduler, worker, worker] Popen, log file)."""
    from distributed import Client
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = open(tmp_path / "dask.log", "w")
    procs = [subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1",
                               "--port", str(port), "--no-dashboard"], env=env, stdout=logs, stderr=logs)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nthreads", "1",
                                           "--nworkers", "1", "--no-dashboard",
                                           "--nanny" if nanny else "--no-nanny"],
                                          env=env, cwd=tmp_path, stdout=logs, stderr=logs))
        with Client(address, timeout="60s") as c:
            c.wait_for_workers(2, timeout=120)
    except BaseException:
        _stop(procs[1:] + procs[:1])
        logs.close()
        raise
    return address, procs, logs


@pytest.mark.slow
def test_killed_worker_loses_no_job(local_run, tmp_path):
    """A real scheduler and two workers (no nanny, so a killed worker stays
    dead); the worker running a shot is killed (SIGKILL) as soon as the shot
    is handed to it: Dask runs its tasks again on the other worker, every job
    ends as on the clean local run, with bitwise the same outputs."""
    import signal
    import time

    from distributed import Client
    job, local_out, _ = local_run
    # the `dask worker` processes run with one BLAS thread (a nanny would set it; here none)
    address, procs, logs = _start_cluster(tmp_path, _env(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
                                                          MKL_NUM_THREADS="1"), nanny=False)
    batch = None
    try:
        with Client(address, timeout="60s") as c:
            by_pid = {pid: addr for addr, pid in c.run(os.getpid).items()}
            assert set(by_pid) == {p.pid for p in procs[1:]}
            batch = subprocess.Popen([sys.executable, "-m", "wearfit_usd", "batch", "-q", str(job), "-o",
                                      str(tmp_path / "out"), "--scheduler", address],
                                     env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            first_seen: dict = {}
            victim = None
            deadline = time.monotonic() + 600
            while victim is None:
                assert batch.poll() is None, "the batch ended before a shot was handed to a worker"
                assert time.monotonic() < deadline
                now = time.monotonic()
                for addr, keys in c.processing().items():
                    for k in keys:
                        first_seen.setdefault(k, now)
                        # a shot handed over just now (it runs for seconds): kill its worker
                        if str(k).startswith("animate-") and now - first_seen[k] < 1.0:
                            victim = (addr, str(k))
                time.sleep(0.05)
            killed = next(p for p in procs[1:] if by_pid.get(p.pid) == victim[0])
            os.kill(killed.pid, signal.SIGKILL)
            killed.wait(timeout=60)
            survivor = next(p for p in procs[1:] if p is not killed)
            stdout, stderr = batch.communicate(timeout=900)
        assert batch.returncode == 1, stderr  # the two jobs that fail on purpose
    finally:
        if batch is not None and batch.poll() is None:
            batch.kill()
            batch.wait(timeout=30)
        _stop(procs[1:] + procs[:1])
        logs.close()
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    local = {j["id"]: j for j in json.loads((local_out / "report.json").read_text())["jobs"]}
    jobs = {j["id"]: j for j in rep["jobs"]}
    # the local run's report may come from its --resume re-run, which leaves the previews out
    assert {i for i in jobs if not i.startswith("preview/")} == {i for i in local if not i.startswith("preview/")}
    for i, j in jobs.items():
        if i not in local:
            assert j["status"] == "ok", (i, j.get("error"))
            continue
        assert j["status"] == local[i]["status"], (i, j.get("error"))
        if j["status"] == "failed":
            assert j["error"] == local[i]["error"]
        elif j["product"] != "preview":
            assert usd_points(j["output"]) == usd_points(local[i]["output"]), i
    # the shot that was running on the killed worker was run again by the other one
    shot = next(j for i, j in jobs.items() if victim[1].startswith(f"animate-{i.split('/', 1)[1]}-"))
    assert shot["status"] == "ok" and shot["worker_pid"] == survivor.pid
    assert 1 <= rep["summary"]["plans_built"] <= 2
