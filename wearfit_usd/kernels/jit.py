"""The numba switch of the kernels: whether numba is in use, and how a
kernel is compiled.

numba is optional (the ``fast`` extra); setting WEARFIT_NO_NUMBA=1 turns it
off even when installed (the tests run the numpy paths that way). numba is
the one optional dependency imported here; no other module of the package
imports it.
"""
from __future__ import annotations

import os

# numba's OpenMP threads (the guard's parallel loop) wait for work asleep,
# not spinning: a spinning thread takes a core from the main thread between
# frames, and on a busy machine that made animate slower than one thread
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

try:  # pragma: no cover - depends on the install
    if os.environ.get("WEARFIT_NO_NUMBA"):
        raise ImportError("disabled by WEARFIT_NO_NUMBA")
    import numba
    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    numba = None
    HAVE_NUMBA = False


def jit(fn=None, *, parallel: bool = False, inline: bool = False):
    """Decorator: numba-compile ``fn`` (cached beside the package); without
    numba, ``fn`` itself (plain Python loops: correct, slow; the public
    kernels run their numpy twins instead). ``@jit`` or
    ``@jit(inline=True, parallel=...)``. ``inline``: small helpers called
    per point or per grid cell are inlined into their callers at numba's IR
    level (as separate functions the grid search took ~30 % longer)."""
    if fn is None:
        return lambda f: jit(f, parallel=parallel, inline=inline)
    if not HAVE_NUMBA:
        return fn
    return numba.njit(cache=True, nogil=True, parallel=parallel, inline="always" if inline else "never")(fn)


# loops over independent items: threads over all cores when compiled
# (numba.prange), a plain loop otherwise
prange = numba.prange if HAVE_NUMBA else range
