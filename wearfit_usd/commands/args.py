"""Argument validators shared by the subcommands.

The ``*_arg`` functions are argparse ``type=`` callables: a bad value ends
in argparse's usage message and exit code 2, never in a traceback. The
``check_*`` functions test what needs several arguments at once (an output
that would overwrite an input) and raise :class:`OutputError`.
"""
from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path

from ..errors import InputError, OutputError

#: output frame rates accepted by ``--fps`` (frames per second)
FPS_MAX = 1000.0
#: body triangles an item vertex may be bound to (``--k``)
K_MAX = 64
#: default bound on the output frame count (``--max-frames``)
MAX_FRAMES = 100_000
USD_SUFFIXES = (".usd", ".usda", ".usdc")


def bounded_int(lo: int, hi: int | None = None):
    """argparse type: an integer in [lo, hi]."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < lo or (hi is not None and v > hi):
            rng = f">= {lo}" if hi is None else f"between {lo} and {hi}"
            raise argparse.ArgumentTypeError(f"must be {rng}, got {v}")
        return v
    parse.__name__ = "integer"
    return parse


def bounded_float(lo: float, hi: float, lo_open: bool = True):
    """argparse type: a finite float in (lo, hi] (or [lo, hi])."""
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(v) or v > hi or v < lo or (lo_open and v == lo):
            raise argparse.ArgumentTypeError(
                f"must be a finite number {'>' if lo_open else '>='} {lo:g} and <= {hi:g}, got {text}")
        return v
    parse.__name__ = "number"
    return parse


def fps_arg(text: str):
    """argparse type for ``--fps``: 'native' (None) or a rate in (0, FPS_MAX]."""
    if str(text).strip().lower() == "native":
        return None
    return bounded_float(0.0, FPS_MAX)(text)


fps_arg.__name__ = "fps"


def start_arg(text: str):
    """argparse type for ``--start``: 'auto' (None: see
    :func:`motion.clip_start.leading_rest_frames`) or a clip frame."""
    if str(text).strip().lower() == "auto":
        return None
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a frame number or 'auto', got {text!r}") from None


start_arg.__name__ = "start"


def check_output(out, inputs=(), suffixes=USD_SUFFIXES, what: str = "output") -> Path:
    """Refuse an output path with another extension, that is a folder, or that
    names one of ``inputs`` (same file after resolving links and ``..``)."""
    out = Path(out)
    if suffixes and out.suffix.lower() not in suffixes:
        raise OutputError(out, f"{what} must end in {', '.join(suffixes[:-1])} or {suffixes[-1]}"
                          if len(suffixes) > 1 else f"{what} must end in {suffixes[0]}")
    if out.is_dir():
        raise OutputError(out, f"{what} is a folder")
    for src in inputs:
        if src is None:
            continue
        if same_file(out, src):
            raise OutputError(out, f"{what} would overwrite the input {src}; choose another name")
    return out


def check_distinct(paths: dict) -> None:
    """Refuse two outputs naming the same file ({option: path})."""
    items = [(k, v) for k, v in paths.items() if v is not None]
    for i, (ka, a) in enumerate(items):
        for kb, b in items[i + 1:]:
            if same_file(a, b):
                raise OutputError(b, f"{kb} names the same file as {ka}")


def same_file(a, b) -> bool:
    """Whether paths ``a`` and ``b`` name the same file (existing or not)."""
    a, b = Path(a), Path(b)
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.realpath(a) == os.path.realpath(b)


def check_inputs(*paths) -> None:
    """Every path exists and is a file."""
    for p in paths:
        if p is None:
            continue
        p = Path(p)
        if not p.exists():
            raise InputError(p, "file not found")
        if p.is_dir():
            raise InputError(p, "is a folder, not a file")


def write_report(path, data) -> None:
    """Write JSON ``data`` to ``path`` atomically (temporary file + rename)."""
    from ..io.usd import atomic_output  # lazy like every command's work: `wearfit --help` stays fast
    text = json.dumps(data, indent=2, default=float)
    with atomic_output(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
