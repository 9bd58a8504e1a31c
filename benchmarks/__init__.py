"""Benchmarks on the real data set (../shared/data): `python3 -m benchmarks [--full]`.

Each ``benchmarks/bench_<stage>.py`` exposes ``run(full: bool, out_dir: Path)
-> list[dict]`` returning table rows; this package runs them, prints one table
per stage, writes ``<out>/<stage>.json``, ``<out>/summary.json`` and a
markdown report ``<out>/REPORT.md`` (with the images the benches wrote).
"""
from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("WEARFIT_DATA", REPO.parent / "shared" / "data"))
USD_DIR = DATA / "usd"
BVH_DIR = DATA / "bvh"
DEFAULT_OUT = REPO / "benchmarks" / "results"
STAGES = ["fit", "dress", "animate", "skinned", "motion", "rigs", "thirdparty", "render", "fuzz", "batch"]


def clip_end(motion, frames: int, fps: float = 30.0, start: int = 1) -> int:
    """``end`` (exclusive clip frame) of the first ``frames`` output frames at
    ``fps`` from clip frame ``start``, whatever the clip's rate; the clip's own end
    when it is shorter (cmu_09_11_run: 166 frames at 120 fps)."""
    return min(start + int(round(frames * motion.fps / fps)), motion.n_frames)


def _columns(rows: list[dict]) -> list[str]:
    """Union of the rows' scalar keys, in first-seen order."""
    cols: list[str] = []
    for r in rows:
        for k in r:
            if k not in cols and not isinstance(r[k], (list, dict)):
                cols.append(k)
    return cols


def _fmt(v) -> str:
    """A table cell: floats to 4 significant digits, None empty."""
    if isinstance(v, float):
        return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.3e}"
    return "" if v is None else str(v)


def format_table(rows: list[dict]) -> str:
    """Rows of dicts -> fixed-width text table (union of keys, in order)."""
    if not rows:
        return "(no rows)"
    cols = _columns(rows)
    cells = [[_fmt(r.get(c)) for c in cols] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
    line = "  ".join(c.ljust(w) for c, w in zip(cols, widths))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(v.ljust(w) for v, w in zip(row, widths)) for row in cells]
    return "\n".join(out)


def markdown_table(rows: list[dict]) -> str:
    if not rows:
        return "(no rows)\n"
    cols = _columns(rows)
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(_fmt(r.get(c)) for c in cols) + " |" for r in rows]
    return "\n".join(out) + "\n"
