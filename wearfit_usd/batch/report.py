"""The batch's report: ``report.json`` (every job's record), ``report.md``
(a table per product, the failures) and ``contact_<target>.png`` (the
previews of each target, one tile per reference)."""
from __future__ import annotations

import json
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
from PIL import Image

from ..render.media import contact_sheet, write_png
from .cache import atomic_write_bytes, code_version


def summary(records: list[dict], seconds: float) -> dict:
    """Counts over the jobs: ok / failed, cache hits / misses, jobs per minute
    (of the jobs computed in this run), the highest peak memory, and the
    dressing plans built in this run (in all and per reference: a task that
    built its plan says so in ``plan_built``)."""
    status = Counter(r["status"] for r in records)
    cache = Counter(r.get("cache", "miss") for r in records)
    computed = [r for r in records if r.get("cache") == "miss" and r["status"] == "ok"]
    peaks = [r["peak_rss_mb"] for r in computed if r.get("peak_rss_mb") is not None]
    plans = Counter(Path(r["reference"]).name for r in computed if r.get("plan_built"))
    return {"plans_built": sum(plans.values()), "plans_built_by_reference": dict(sorted(plans.items())),
            "jobs": len(records), "ok": status.get("ok", 0), "failed": status.get("failed", 0),
            "cache_hits": cache.get("hit", 0), "cache_misses": cache.get("miss", 0),
            "computed": len(computed), "wall_seconds": round(seconds, 3),
            "jobs_per_minute": round(60.0 * len(computed) / seconds, 2) if seconds > 0 and computed else 0.0,
            "max_peak_rss_mb": max(peaks) if peaks else None}


def _fmt(v, nd=2):
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def _worst(figures: dict, measure: str) -> float | None:
    """The largest worst-frame value of a motion measure over a shot's items
    (:func:`~wearfit_usd.animate.measures.worst_frames`), None if none applies."""
    vals = [m[measure]["value"] for m in (figures.get("motion_worst") or {}).values()
            if m.get(measure, {}).get("value") is not None]
    return max(vals) if vals else None


def _main_figures(rec: dict) -> str:
    f = rec.get("figures") or {}
    p = rec["product"]
    if p == "fit":
        return (f"fit->target mean {_fmt(f.get('fit_to_target_mean_mm'))} mm, p99 {_fmt(f.get('fit_to_target_p99_mm'))}"
                f" mm; flipped {_fmt(f.get('flipped_triangles'))}")
    if p == "dress":
        return (f"new penetration {_fmt(f.get('new_penetration_pct'))} %, clearance change p95 "
                f"{_fmt(f.get('clearance_change_p95_mm'))} mm")
    if p == "animate":
        return (f"{f.get('frames')} frames; new penetration worst frame "
                f"{_fmt(f.get('worst_frame_new_penetration_pct'))} %, mean {_fmt(f.get('mean_new_penetration_pct'))} %"
                f"; worst item: stretch p99 {_fmt(_worst(f, 'stretch_p99'))}x, coverage loss "
                f"{_fmt(_worst(f, 'coverage_loss_pct'))} %, separation p95 {_fmt(_worst(f, 'separation_p95_mm'))} mm")
    return ""


def contact_sheets(records: list[dict], outdir: Path) -> list[Path]:
    """One ``contact_<target>.png`` per target with a preview: its previews
    (one per reference) side by side."""
    by_target = defaultdict(list)
    for r in records:
        if r["product"] == "preview" and r["status"] == "ok":
            by_target[Path(r["target"]).stem].append(r["output"])
    written = []
    for tgt, paths in sorted(by_target.items()):
        images = [np.asarray(Image.open(p).convert("RGB")) for p in sorted(paths)]
        sheet = contact_sheet(images, columns=len(images))
        written.append(write_png(sheet, outdir / f"contact_{tgt}.png"))
    return written


def write_report(records: list[dict], outdir, seconds: float, jobs_file, cluster: dict,
                 intermediates: dict | None = None) -> dict:
    """Write ``report.json``, ``report.md`` and the contact sheets under ``outdir``.

    Parameters
    ----------
    records : list of dict
        One per job (see :func:`.graph.run_batch`).
    outdir : Path
        The batch's output folder.
    seconds : float
        Wall time of the run.
    jobs_file : Path
        The job file (named in the report).
    cluster : dict
        The scheduler address, worker count, dashboard link.
    intermediates : dict, optional
        The shared tasks submitted (reads, fits) and each reference's plan
        worker (:attr:`.graph.BatchResult.intermediates`).

    Returns
    -------
    dict
        The summary (see :func:`summary`), as written under ``"summary"``.
    """
    outdir = Path(outdir)
    summ = summary(records, seconds)
    sheets = [str(p) for p in contact_sheets(records, outdir)]
    doc = {"jobs_file": str(jobs_file), "code_version": code_version(), "cluster": cluster,
           "summary": summ, "intermediates": intermediates or {}, "contact_sheets": sheets, "jobs": records}
    atomic_write_bytes(outdir / "report.json", json.dumps(doc, indent=1, default=float).encode())
    lines = [f"# wearfit batch: {Path(jobs_file).name}", "",
             f"{summ['ok']} of {summ['jobs']} jobs ok, {summ['failed']} failed; cache hits {summ['cache_hits']}, "
             f"computed {summ['computed']}; {summ['wall_seconds']:.1f} s wall, {summ['jobs_per_minute']} jobs/min on "
             f"{cluster.get('workers')} worker(s) ({cluster.get('scheduler')}); peak worker memory "
             f"{_fmt(summ['max_peak_rss_mb'], 0)} MiB; dressing plans built {summ['plans_built']}"
             + (f" ({', '.join(f'{k}: {v}' for k, v in summ['plans_built_by_reference'].items())})"
                if summ["plans_built"] else ""), ""]
    failed = [r for r in records if r["status"] == "failed"]
    if failed:
        lines += ["## Failures", ""] + [f"- `{r['id']}`: {r['error']}" for r in failed] + [""]
    for product in ("fit", "dress", "animate", "preview"):
        rows = [r for r in records if r["product"] == product and r["status"] == "ok"]
        if not rows:
            continue
        lines += [f"## {product}", "", "| job | cache | seconds | peak MiB | figures |", "|---|---|---|---|---|"]
        for r in rows:
            lines.append(f"| `{Path(r['output']).name}` | {r.get('cache')} | {_fmt(r.get('seconds'))} | "
                         f"{_fmt(r.get('peak_rss_mb'), 0)} | {_main_figures(r)} |")
        lines.append("")
    if sheets:
        lines += ["## Contact sheets", ""] + [f"![{Path(s).stem}]({Path(s).name})" for s in sheets] + [""]
    atomic_write_bytes(outdir / "report.md", "\n".join(lines).encode())
    return summ
