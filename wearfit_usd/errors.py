"""Exceptions with messages that name the file and the problem.

The CLI turns any :class:`WearfitError` into a one-line message on stderr and
a non-zero exit code (2 for bad input, 1 for other failures).
"""
from __future__ import annotations


class WearfitError(Exception):
    """Base class: a problem the user can act on."""
    exit_code = 1


class InputError(WearfitError):
    """Bad or unsupported input file or argument (exit code 2)."""
    exit_code = 2

    def __init__(self, path, message: str, line: int | None = None):
        self.path = str(path) if path is not None else None
        self.line = line
        where = self.path or "<input>"
        if line is not None:
            where = f"{where}:{line}"
        super().__init__(f"{where}: {message}")
        self.message = message


class BVHError(InputError):
    """Malformed BVH file (truncated, wrong channel count, bad rotation order...)."""


class USDInputError(InputError):
    """A USD stage lacks what the tool needs (skinned mesh, weights, joints...)."""


class GeometryError(InputError):
    """Geometry that cannot be processed (NaN points, empty or degenerate mesh)."""


class OutputError(InputError):
    """An output the tool refuses to write (it would overwrite an input, wrong
    extension, too large to hold in memory)."""


class NonFiniteError(InputError):
    """A computation produced NaN/inf (from extreme input values); names the
    frame and joint or mesh where it happened."""


class WriteError(WearfitError):
    """An output could not be written (disk full, no permission...); nothing
    half-written is left behind (exit code 1)."""

    def __init__(self, path, message: str):
        self.path = str(path)
        super().__init__(f"{self.path}: {message}")
