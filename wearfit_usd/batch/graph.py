"""The Dask task graph of a batch, and the tasks the workers run.

Shared intermediate results, each computed once per batch:

- ``read``: every input USD stage is read once (a :class:`~wearfit_usd.model.Character`
  shipped to the tasks that use it);
- ``fit``: the reference body fitted onto each target once
  (:func:`~wearfit_usd.fit.body_fit.fit_character`), used by the ``fit`` and the
  ``dress`` products, and cached on disk;
- the dressing plan of each reference (:func:`~wearfit_usd.dress.plan.plan`):
  a plan holds a CHOLMOD factor, which cannot be pickled, so it cannot travel
  between processes; instead every task that needs it (``dress`` and
  ``animate``, every target and clip) is pinned to one worker per reference
  (:func:`assign_owners`; Dask's loose restrictions, so a lost worker's tasks
  still move elsewhere), which builds the plan once and keeps it
  (:func:`_plan_of`). Each record says whether its task built the plan
  (``plan_built``); the report sums them;
- ``preview`` renders the dressed target of the ``dress`` product.

``animate`` dresses each clip's first-frame pose itself (as ``wearfit animate``
does) from the shared reads and the reference's plan.

Products are skipped entirely when their cached result is complete (with
``resume``); the intermediates are only submitted when some product needs them.
Tasks raise :class:`JobError` (a plain picklable message naming the input and
the problem); Dask reschedules the tasks of a lost worker by itself
(``distributed.scheduler.allowed-failures``).
"""
from __future__ import annotations

import functools
import os
import pickle
import resource
import time
import uuid
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..animate.try_on import AnimateOptions, animate
from ..commands.fit import fitted_character
from ..commands.output_options import write_dressed
from ..dress.apply import dress
from ..dress.metrics import dress_report
from ..dress.plan import plan
from ..errors import InputError
from ..fit.body_fit import fit_character
from ..io.bvh import read_bvh
from ..io.usd import read_character, write_character
from ..io.usd_carry import CarryPlan
from ..progress import set_verbosity
from ..render.media import write_png
from .cache import Cache, atomic_write_bytes, file_digest, publish, result_key
from .jobs import Job, JobSet

FIT_OPTIONS = {"pose_align": True, "same_topology_shortcut": True}


class JobError(RuntimeError):
    """A job's failure as one line (picklable, unlike errors with extra fields)."""


def _fails_cleanly(task):
    """A task whose :class:`JobError` carries no chained exception: Dask
    pickles an error with its ``__context__``, and the project's errors with
    extra fields cannot be unpickled, which would turn the message into a
    ``JobError("...")`` repr."""
    @functools.wraps(task)
    def run(*args, **kwargs):
        try:
            return task(*args, **kwargs)
        except JobError as exc:
            error = JobError(str(exc))
        raise error  # outside the handler: no context

    return run


# ----------------------------------------------------------------------------
# worker side

def _quiet_worker() -> None:
    set_verbosity(0)
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")


def _reset_peak_rss() -> None:
    """Reset the process's RSS high-water mark (Linux ``clear_refs`` 5), so
    the next :func:`_peak_rss_mb` measures one task (one thread per worker)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _peak_rss_mb() -> float:
    """The worker process's peak resident memory in MiB (``VmHWM``, else
    ``getrusage``'s lifetime maximum)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class _Task:
    """Context of one task: quiet output, timing, peak memory, captured
    warnings, and any exception turned into a :class:`JobError` naming ``what``."""

    def __init__(self, what: str):
        self.what = what
        self.warnings: list[str] = []

    def __enter__(self):
        _quiet_worker()
        _reset_peak_rss()
        self._w = warnings.catch_warnings(record=True)
        self._caught = self._w.__enter__()
        warnings.simplefilter("always")
        self.t0 = time.perf_counter()
        self.cpu0 = time.process_time()
        return self

    def __exit__(self, kind, exc, tb):
        self.seconds = time.perf_counter() - self.t0
        self.cpu_seconds = time.process_time() - self.cpu0
        self.peak_rss_mb = _peak_rss_mb()
        self._w.__exit__(None, None, None)
        self.warnings = list(dict.fromkeys(str(w.message) for w in self._caught))
        if exc is not None and not isinstance(exc, JobError) and isinstance(exc, Exception):
            raise JobError(f"{self.what}: {type(exc).__name__}: {exc}") from None
        return False

    def stats(self) -> dict:
        return {"seconds": round(self.seconds, 3), "cpu_seconds": round(self.cpu_seconds, 3),
                "peak_rss_mb": round(self.peak_rss_mb, 1),
                "warnings": self.warnings, "worker_pid": os.getpid()}


@_fails_cleanly
def task_read(path: str, role: str):
    """Read one USD stage (a reference with its skeleton, a target with or without)."""
    with _Task(f"reading {role} {path}"):
        if not Path(path).exists():
            raise JobError(f"{path}: file not found")
        return read_character(path, require_skeleton=(role == "reference"))


@_fails_cleanly
def task_fit(reference, target, cache_root: str, key: str, resume: bool):
    """The reference body fitted onto the target (a :class:`FitResult`),
    loaded from the cache when ``resume`` and stored there."""
    obj = Cache(cache_root).object_path(key, ".fit.pkl")
    with _Task(f"fitting {Path(reference.source).name} onto {target.source}"):
        if resume and obj.exists():
            try:
                return pickle.loads(obj.read_bytes())
            except (OSError, pickle.UnpicklingError, EOFError):
                pass
        result = fit_character(reference, target, dict(FIT_OPTIONS))
        atomic_write_bytes(obj, pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
        return result


_PLANS: dict = {}
PLANS_KEPT = 2  # plans a worker keeps (the most recently used): a plan of a MakeHuman outfit is ~50-100 MB


def _plan_of(reference, key: str, k: int):
    """The dressing plan of ``reference``, built once per worker process
    (keyed by the reference's content and the options); returns (plan, built)."""
    built = key not in _PLANS
    p = plan(reference, k=k) if built else _PLANS.pop(key)
    _PLANS[key] = p  # most recent last
    while len(_PLANS) > PLANS_KEPT:
        _PLANS.pop(next(iter(_PLANS)))
    return p, built


def _record(meta: dict, task: _Task, obj: Path, figures: dict, **extra) -> dict:
    rec = dict(meta, object=str(obj), status="ok", figures=figures, **task.stats(), **extra)
    Cache(meta["cache_root"]).store_record(meta["key"], rec)
    return rec


@_fails_cleanly
def task_fit_product(reference, target, fit, meta: dict) -> dict:
    """Write the fitted body (as ``wearfit fit``)."""
    obj = Cache(meta["cache_root"]).object_path(meta["key"], meta["suffix"])
    with _Task(f"writing the fitted body of {meta['id']}") as t:
        char = fitted_character(reference, target, fit)
        write_character(obj, char, items=[], up_axis=target.up_axis, meters_per_unit=target.meters_per_unit,
                        carry_plan=CarryPlan.for_dress(reference, target, [], body_from_reference=True))
        d = fit.diagnostics
        figures = {k: d.get(k) for k in ("fit_to_target_mean_mm", "fit_to_target_p99_mm", "target_to_fit_mean_mm",
                                          "target_to_fit_p99_mm", "flipped_triangles", "time_total_fit_s")
                   if d.get(k) is not None}
        figures["same_topology"] = bool(fit.same_topology)
        t.warnings += list(fit.warnings)
    return _record(meta, t, obj, figures)


@_fails_cleanly
def task_dress(reference, target, fit, plan_key: str, meta: dict) -> dict:
    """Dress the target with the reference's items (as ``wearfit dress``),
    on the shared fit and this worker's plan of the reference."""
    obj = Cache(meta["cache_root"]).object_path(meta["key"], meta["suffix"])
    with _Task(f"dressing {meta['id']}") as t:
        if not reference.items:
            raise InputError(reference.source, "the reference holds no wearable items (no Mesh besides the body)")
        p, built = _plan_of(reference, plan_key, meta["k"])
        res = dress(reference, target, k=meta["k"], prepared=p,
                    body_points=np.asarray(fit.points, dtype=np.float64))
        # as `wearfit dress` with its defaults (the skinned copies fitted to example poses)
        write_dressed(obj, reference, target, res, ref_plan=p)
        rows = dress_report(reference, target, res)
        figures = {"items": rows,
                   "new_penetration_pct": max((r["new_pen_pct"] for r in rows), default=0.0),
                   "clearance_change_p95_mm": max((r["clear_p95_mm"] for r in rows), default=0.0),
                   "timings_s": res.timings}
    return _record(meta, t, obj, figures, plan_built=built)


@_fails_cleanly
def task_animate(reference, target, plan_key: str, meta: dict) -> dict:
    """One shot (as ``wearfit animate``), streamed to the cache, on this
    worker's plan of the reference."""
    obj = Cache(meta["cache_root"]).object_path(meta["key"], meta["suffix"])
    with _Task(f"animating {meta['id']}") as t:
        clip = meta["clip"]
        if not Path(clip["path"]).exists():
            raise JobError(f"{clip['path']}: file not found")
        motion = read_bvh(clip["path"])
        opts = AnimateOptions(k=meta["k"], start=clip["start"], end=clip["end"], fps=meta["fps"],
                              measure_every=meta["measure_every"], hidden_body="subset",
                              carry_plan=CarryPlan.for_dress(reference, target, reference.items))
        p, built = _plan_of(reference, plan_key, meta["k"])
        rep = animate(reference, target, motion, obj, opts, ref_plan=p)
        figures = {"frames": rep.frames, "fps": rep.fps,
                   "worst_frame_new_penetration_pct": 100 * rep.worst_frame_penetration,
                   "mean_new_penetration_pct": (100 * sum(rep.per_frame_penetration) / len(rep.per_frame_penetration)
                                                if rep.per_frame_penetration else None),
                   "motion_worst": rep.motion_worst, "cloth_vertices": rep.cloth_vertices,
                   "timings_s": {k: v for k, v in rep.timings.items() if not isinstance(v, dict)}}
    return _record(meta, t, obj, figures, plan_built=built)


@_fails_cleanly
def task_preview(dressed, meta: dict) -> dict:
    """A front view of the dressed target (a PNG)."""
    from ..render.preview import render_frames  # pyrender/OpenGL: loaded by preview tasks only
    obj = Cache(meta["cache_root"]).object_path(meta["key"], ".png")
    src = dressed["object"] if isinstance(dressed, dict) else dressed
    with _Task(f"rendering {meta['id']}") as t:
        images = render_frames(src, size=tuple(meta["size"]), camera="front", show_progress=False)
        write_png(images[0], obj)
    # a dressing made for this preview only (no dress job) counts its plan here
    built = bool(meta.get("own_dress") and isinstance(dressed, dict) and dressed.get("plan_built"))
    return _record(meta, t, obj, {"size": meta["size"]}, plan_built=built)


# ----------------------------------------------------------------------------
# client side

@dataclass
class BatchResult:
    records: list[dict]
    seconds: float
    intermediates: dict = field(default_factory=dict)


def output_path(outdir: Path, job: Job, fmt: str) -> Path:
    """Where a job's product lands: ``OUTDIR/<product>/<name>.<fmt>`` (PNG for previews)."""
    return outdir / job.product / f"{job.name}.{'png' if job.product == 'preview' else fmt}"


def _job_key(job: Job, digests: dict, opts: dict) -> str:
    ref, tgt = digests[job.reference], digests[job.target]
    if job.product == "fit":
        return result_key("fit-product", [ref, tgt], {**FIT_OPTIONS, "format": opts["format"]})
    if job.product == "dress":
        return result_key("dress", [ref, tgt], {"k": opts["k"], "format": opts["format"]})
    if job.product == "preview":
        return result_key("preview", [ref, tgt], {"k": opts["k"], "size": opts["preview_size"]})
    c = job.clip
    start = "auto" if c.start is None else c.start
    return result_key("animate", [ref, tgt, digests[c.path]],
                      {"k": opts["k"], "start": start, "end": c.end, "fps": opts["fps"],
                       "format": opts["format"], "measure_every": MEASURE_EVERY})


MEASURE_EVERY = 5  # exact penetration figures of a shot every N frames (does not change the shot)
PLANNED = ("dress", "animate", "preview")  # products whose tasks need the reference's plan (preview: its dressing)


def assign_owners(jobs: list[Job], workers: list[str], per_reference: int = 1) -> dict[Path, list[str]]:
    """The workers that build and use each reference's dressing plan.

    References are dealt out heaviest first to the least loaded workers, the
    load being the number of jobs that need the plan (``dress``, ``animate``
    and the dressing behind a ``preview``), shared evenly by a reference's
    workers; ties go to the worker listed first.

    Parameters
    ----------
    jobs : list of Job
        The jobs to run.
    workers : list of str
        Worker addresses (sorted by the caller for a reproducible deal).
    per_reference : int
        Workers per reference (each builds the plan once): 1 builds every
        plan once; more spread a reference's shots over more workers.

    Returns
    -------
    dict
        ``{reference path: [worker address, ...]}``; empty without workers.
    """
    if not workers:
        return {}
    n = max(1, min(per_reference, len(workers)))
    load: dict[Path, int] = {}
    for j in jobs:
        load[j.reference] = load.get(j.reference, 0) + (j.product in PLANNED)
    busy = dict.fromkeys(workers, 0.0)
    owners = {}
    for ref in sorted(load, key=lambda r: -load[r]):  # stable: file order among equals
        group = sorted(workers, key=lambda a: busy[a])[:n]  # stable: listed order among equals
        owners[ref] = group
        for w in group:
            busy[w] += load[ref] / n
    return owners


def run_batch(jobset: JobSet, outdir, client, resume: bool = False, previews: bool = True,
              on_done=None, plan_workers: int = 1) -> BatchResult:
    """Run every job of ``jobset`` on the Dask ``client``; place the products under ``outdir``.

    Parameters
    ----------
    jobset : JobSet
        From :func:`.jobs.load_jobs`.
    outdir : Path
        Output folder (products, ``.cache``); shared with the workers.
    client : distributed.Client
        A local or remote cluster's client.
    resume : bool
        Reuse complete cached results whose key (input bytes, options, code) matches.
    previews : bool
        Run the ``preview`` jobs (else they are left out of the batch).
    on_done : callable, optional
        Called with each finished job's record (progress).
    plan_workers : int
        Workers per reference for its dressings and shots (:func:`assign_owners`).

    Returns
    -------
    BatchResult
        One record per job (status ok/failed, cache hit/miss, output, figures,
        seconds, peak memory, error), in job order.
    """
    from distributed import as_completed

    t_start = time.perf_counter()
    outdir = Path(outdir).resolve()
    cache = Cache(outdir / ".cache")
    opts = jobset.options
    fmt = opts["format"]
    run = uuid.uuid4().hex[:6]
    jobs = [j for j in jobset.jobs if previews or j.product != "preview"]

    digests: dict[Path, str] = {}
    missing: dict[Path, str] = {}
    for p in jobset.inputs():
        try:
            digests[p] = file_digest(p)
        except OSError as exc:
            missing[p] = f"{p}: {'file not found' if isinstance(exc, FileNotFoundError) else exc}"

    records: dict[Job, dict] = {}
    todo: list[tuple[Job, str]] = []
    for job in jobs:
        base = {"id": job.id, "product": job.product, "reference": str(job.reference), "target": str(job.target),
                "clip": None if job.clip is None else {"path": str(job.clip.path), "start": job.clip.start,
                                                       "end": job.clip.end},
                "output": str(output_path(outdir, job, fmt))}
        bad = [missing[p] for p in (job.reference, job.target, job.clip.path if job.clip else None) if p in missing]
        if bad:
            records[job] = dict(base, status="failed", cache="miss", error="; ".join(bad))
            continue
        key = _job_key(job, digests, opts)
        hit = cache.lookup(key) if resume else None
        if hit is not None:
            records[job] = dict(hit, **base, cache="hit")
        else:
            todo.append((job, key))
            records[job] = dict(base, key=key)

    # the graph: shared reads, fits and dressings, then the products
    cache_root = str(cache.root)
    reads, fits, dressed = {}, {}, {}
    counts = {"read": 0, "fit": 0}

    def read(path: Path, role: str):
        if (path, role) not in reads:
            reads[path, role] = client.submit(task_read, str(path), role, pure=False,
                                              key=f"read-{path.stem}-{digests[path][:8]}-{run}")
            counts["read"] += 1
        return reads[path, role]

    def fit(job: Job):
        pair = (job.reference, job.target)
        if pair not in fits:
            key = result_key("fit", [digests[job.reference], digests[job.target]], FIT_OPTIONS)
            fits[pair] = client.submit(task_fit, read(job.reference, "reference"), read(job.target, "target"),
                                       cache_root, key, resume, pure=False,
                                       key=f"fit-{job.reference.stem}-{job.target.stem}-{key[:8]}-{run}")
            counts["fit"] += 1
        return fits[pair]

    def meta(job: Job, key: str) -> dict:
        return dict(records[job], key=key, cache_root=cache_root, suffix=f".{fmt}", k=opts["k"],
                    fps=opts["fps"], size=opts["preview_size"], measure_every=MEASURE_EVERY)

    plan_keys = {r: result_key("plan", [digests[r]], {"k": opts["k"]}) for r in digests}
    # each reference's planned tasks on its worker(s) (loose: elsewhere if lost), submitted
    # reference by reference so a worker owning several finishes one plan's tasks first
    owners = assign_owners([j for j, _ in todo], sorted(client.scheduler_info().get("workers", {})), plan_workers)
    order = {r: i for i, r in enumerate(dict.fromkeys(j.reference for j in jobs))}
    todo.sort(key=lambda jk: order[jk[0].reference])

    def pinned(job: Job) -> dict:
        group = owners.get(job.reference)
        return {"workers": group, "allow_other_workers": True} if group else {}

    futures, own_dress = {}, set()
    for job, key in todo:
        name = f"{job.product}-{job.name}-{key[:8]}-{run}"
        ref, tgt = read(job.reference, "reference"), None
        if job.product in ("fit", "dress", "animate"):
            tgt = read(job.target, "target")
        if job.product == "fit":
            f = client.submit(task_fit_product, ref, tgt, fit(job), meta(job, key), pure=False, key=name)
        elif job.product == "dress":
            f = client.submit(task_dress, ref, tgt, fit(job), plan_keys[job.reference], meta(job, key),
                              pure=False, key=name, **pinned(job))
            dressed[job.reference, job.target] = f
        elif job.product == "animate":
            f = client.submit(task_animate, ref, tgt, plan_keys[job.reference], meta(job, key), pure=False,
                              key=name, **pinned(job))
        else:
            continue
        futures[f] = job
    for job, key in todo:  # previews after the dressings they show
        if job.product != "preview":
            continue
        pair = (job.reference, job.target)
        src = dressed.get(pair)
        if src is None:
            djob = Job("dress", job.reference, job.target)
            drec = records.get(djob)
            if drec is not None and drec.get("status") == "ok":  # a cache hit
                src = drec["object"]
            else:  # no dress job in the batch: dress for the preview only
                dkey = _job_key(djob, digests, opts)
                hit = cache.lookup(dkey) if resume else None
                if hit is not None:
                    src = hit["object"]
                else:
                    src = client.submit(task_dress, read(job.reference, "reference"), read(job.target, "target"),
                                        fit(djob), plan_keys[job.reference],
                                        dict(meta(job, dkey), id=djob.id, product="dress"), pure=False,
                                        key=f"dress-{djob.name}-{dkey[:8]}-{run}", **pinned(job))
                    own_dress.add(pair)
            dressed[pair] = src
        f = client.submit(task_preview, src, dict(meta(job, key), own_dress=pair in own_dress), pure=False,
                          key=f"preview-{job.name}-{key[:8]}-{run}")
        futures[f] = job

    for job in jobs:  # known before running: cache hits and missing inputs
        rec = records[job]
        if "status" in rec:
            if rec["status"] == "ok":
                publish(rec["object"], rec["output"])
            if on_done is not None:
                on_done(rec)
    for fut in as_completed(list(futures)):
        job = futures[fut]
        base = records[job]
        if fut.status == "finished":
            rec = dict(fut.result(), output=base["output"], cache="miss")
            rec.pop("cache_root", None)
            publish(rec["object"], rec["output"])
        else:
            exc = fut.exception()
            rec = dict(base, status="failed", cache="miss", error=str(exc) or type(exc).__name__)
        records[job] = rec
        if on_done is not None:
            on_done(rec)
        fut.release()
    for rec in records.values():
        for k in ("cache_root", "suffix", "size", "measure_every", "own_dress"):
            rec.pop(k, None)
    counts["owners"] = {str(r): w for r, w in owners.items()}
    return BatchResult([records[j] for j in jobs], time.perf_counter() - t_start, counts)
