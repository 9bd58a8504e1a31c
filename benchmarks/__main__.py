"""Run the benchmarks: `python3 -m benchmarks [--full] [--only fit,dress] [--out DIR]`."""
from __future__ import annotations

import argparse
import importlib
import json
import platform
import sys
import time
import traceback
from pathlib import Path

from benchmarks import DATA, DEFAULT_OUT, STAGES, format_table, markdown_table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python3 -m benchmarks", description=__doc__)
    ap.add_argument("--full", action="store_true", help="every target, item and clip (slow)")
    ap.add_argument("--only", default=None, help="comma-separated stages: " + ",".join(STAGES))
    ap.add_argument("--out", default=str(DEFAULT_OUT), help="output folder for JSON and the report")
    args = ap.parse_args(argv)
    if not DATA.exists():
        print(f"benchmarks: data set not found at {DATA} (set WEARFIT_DATA)", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stages = args.only.split(",") if args.only else STAGES
    summary = {"full": args.full, "python": platform.python_version(), "machine": platform.machine(),
               "stages": {}}
    md = ["# wearfit_usd benchmark report", "",
          f"Mode: {'full' if args.full else 'quick'}. Data: `{DATA}`. "
          "Ratios compare methods run in the same process on the same inputs.", ""]
    failed = []
    for stage in stages:
        try:
            mod = importlib.import_module(f"benchmarks.bench_{stage}")
        except ModuleNotFoundError as exc:
            print(f"[{stage}] not available: {exc}", file=sys.stderr)
            failed.append(stage)
            continue
        print(f"\n== {stage} ==", flush=True)
        t0 = time.perf_counter()
        try:
            rows = mod.run(args.full, out)
        except Exception:
            traceback.print_exc()
            failed.append(stage)
            continue
        dt = time.perf_counter() - t0
        print(format_table(rows))
        print(f"({stage}: {dt:.1f} s)")
        (out / f"{stage}.json").write_text(json.dumps(rows, indent=2, default=float))
        summary["stages"][stage] = {"seconds": dt, "rows": rows}
        md += [f"## {stage}", "", markdown_table(rows)]
        images = sorted(p for p in out.glob(f"{stage}_*.png"))
        for img in images:
            md.append(f"![{img.stem}]({img.name})")
        md.append("")
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
    (out / "REPORT.md").write_text("\n".join(md))
    print(f"\nwrote {out / 'summary.json'} and {out / 'REPORT.md'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
