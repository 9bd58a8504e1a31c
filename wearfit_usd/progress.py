"""Progress reporting for long work (frames, iterations), silenced by --quiet.

A single module-level verbosity switch set by the CLI; library code calls
:func:`progress` to wrap an iterable and :func:`info` / :func:`warn` to talk.
Bars go to stderr through tqdm, only when stderr is a terminal: a log file
or pipe would get one carriage-return-separated redraw per update.
"""
from __future__ import annotations

import sys
import warnings
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

# 0 = quiet (warnings only), 1 = normal, 2 = verbose
_LEVEL = 1


def set_verbosity(level: int) -> None:
    global _LEVEL
    _LEVEL = int(level)


def verbosity() -> int:
    return _LEVEL


def info(msg: str) -> None:
    if _LEVEL >= 1:
        print(msg, file=sys.stderr, flush=True)


def debug(msg: str) -> None:
    if _LEVEL >= 2:
        print(msg, file=sys.stderr, flush=True)


def warn(msg: str) -> None:
    """Always shown (also under --quiet) and recorded as a Python warning."""
    warnings.warn(msg, stacklevel=2)


def _stderr_is_terminal() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stream
        return False


def progress(iterable: Iterable[T], total: int | None = None, desc: str = "",
             unit: str = "it") -> Iterator[T]:
    """Wrap ``iterable`` in a progress bar unless quiet or stderr is not a terminal."""
    if _LEVEL < 1 or not _stderr_is_terminal():
        return iter(iterable)
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a declared dependency
        return iter(iterable)
    return iter(tqdm(iterable, total=total, desc=desc, unit=unit, file=sys.stderr,
                     leave=False, dynamic_ncols=True, mininterval=0.25))
