"""Atomic file output: write beside the destination, rename into place.

A crash or an exception never leaves a half-written file at the
destination (:func:`atomic_output`, used by the USD and BVH writers).
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


def atomic_output(path):
    """Context manager: yields a temporary path beside ``path`` with the same
    extension; renames it to ``path`` on success, deletes it on failure.

    The temporary file does not exist when the block starts (``Sdf`` wants
    to create it itself); the block writes it.
    """

    @contextlib.contextmanager
    def _cm():
        dest = Path(path)
        dest.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{dest.stem}.", suffix=dest.suffix or ".usd",
                                   dir=str(dest.parent))
        os.close(fd)
        os.unlink(tmp)  # Sdf wants to create the file itself
        try:
            yield tmp
            os.replace(tmp, dest)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
    return _cm()
