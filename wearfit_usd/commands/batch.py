"""`wearfit batch JOBS -o OUTDIR`: references x targets x clips on Dask."""
from __future__ import annotations

import importlib.util
import os
import sys
import urllib.request
from pathlib import Path

from ..errors import InputError


def register(sub, common):
    p = sub.add_parser(
        "batch", parents=[common],
        help="run fit/dress/animate/preview over many references, targets and clips on Dask",
        description="Run a job file (JSON, YAML or CSV: references, targets, clips, products) on a "
                    "Dask cluster: by default a local cluster of worker processes, or an existing "
                    "scheduler. Shared results (each read, each body fit, each reference's dressing "
                    "plan) are computed once; every result is cached by the bytes of its inputs, its "
                    "options and the code version. Writes OUTDIR/<product>/<reference>__<target>[__clip].usd, "
                    "OUTDIR/report.json, OUTDIR/report.md and a contact sheet per target.")
    p.add_argument("jobs", help="job file (.json, .yaml/.yml or .csv)")
    p.add_argument("-o", "--out", required=True, metavar="OUTDIR", help="output folder")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="an existing Dask scheduler (tcp://host:8786); default: a local cluster")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes of the local cluster (default: the machine's cores)")
    p.add_argument("--resume", action="store_true",
                   help="reuse the complete results already in OUTDIR whose inputs, options and code match")
    p.add_argument("--no-previews", action="store_true", help="skip the preview jobs and contact sheets")
    p.add_argument("--plan-workers", type=int, default=1, metavar="N",
                   help="workers that dress and animate each reference, each building its dressing plan once "
                        "(default 1: every plan built once; more spread few references over many workers)")
    p.set_defaults(func=run)
    return p


def _client(args):
    """A Dask client: on ``--scheduler``, or on a new local cluster of processes."""
    import logging

    import dask
    from distributed import Client, LocalCluster
    if args.scheduler:
        try:
            return Client(args.scheduler, timeout="30s"), None
        except OSError as exc:
            raise InputError(None, f"cannot reach the Dask scheduler {args.scheduler}: {exc}") from None
    n = args.workers or os.cpu_count() or 1
    # Dask's dashboard needs bokeh: started (on a free port) only when it is installed
    dashboard = ":0" if importlib.util.find_spec("bokeh") is not None else None
    # no work stealing: each reference's tasks stay on the worker that holds its plan
    # (batch.graph.assign_owners); an idle worker would otherwise build the plan again
    with dask.config.set({"distributed.scheduler.work-stealing": False}):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=dashboard,
                               silence_logs=logging.ERROR)
    return Client(cluster), cluster


def _dashboard(client) -> str | None:
    """The dashboard's address when the scheduler serves one (its HTTP
    service answers 404 there when bokeh is missing: then None)."""
    try:
        if "dashboard" not in client.scheduler_info().get("services", {}):
            return None
        link = client.dashboard_link
        with urllib.request.urlopen(link, timeout=3) as page:
            return link if page.status == 200 else None
    except (AttributeError, KeyError, OSError, ValueError):
        return None


def run(args) -> int:
    from ..batch.graph import run_batch
    from ..batch.jobs import load_jobs
    from ..batch.report import write_report
    from ..progress import info, verbosity

    jobset = load_jobs(args.jobs)
    if args.workers is not None and args.workers < 1:
        raise InputError(None, f"--workers must be >= 1 (got {args.workers})")
    if args.plan_workers < 1:
        raise InputError(None, f"--plan-workers must be >= 1 (got {args.plan_workers})")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    client, cluster = _client(args)
    try:
        n_workers = len(client.scheduler_info().get("workers", {}))
        dashboard = _dashboard(client)
        info(f"batch: {len(jobset.jobs)} jobs on {n_workers} worker(s) at {client.scheduler.address}"
             + (f"; dashboard {dashboard}" if dashboard else ""))
        bar = None
        if verbosity() >= 1:
            from ..progress import progress
            # a bar advanced by hand: one step per finished job (an endless iterable of zeros)
            bar = progress(iter(int, 1), total=len(jobset.jobs), desc="batch", unit="job")
        failures = []

        def on_done(rec):
            if bar is not None:
                next(bar)
            if rec["status"] == "failed":
                failures.append(rec)

        result = run_batch(jobset, out, client, resume=args.resume, previews=not args.no_previews,
                           on_done=on_done, plan_workers=args.plan_workers)
        if bar is not None and hasattr(bar, "close"):
            bar.close()
        summ = write_report(result.records, out, result.seconds, jobset.source,
                            {"scheduler": client.scheduler.address, "workers": n_workers,
                             "dashboard": dashboard, "local": cluster is not None}, result.intermediates)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    for rec in failures:
        print(f"wearfit batch: {rec['id']} failed: {rec['error']}", file=sys.stderr)
    info(f"batch: {summ['ok']} of {summ['jobs']} jobs ok, {summ['failed']} failed; cache hits "
         f"{summ['cache_hits']}, computed {summ['computed']} ({summ['plans_built']} dressing plans built) in "
         f"{summ['wall_seconds']:.1f} s "
         f"({summ['jobs_per_minute']} jobs/min); report {out / 'report.md'}")
    return 1 if summ["failed"] else 0
