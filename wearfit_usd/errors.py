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
