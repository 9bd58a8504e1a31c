"""Per-frame evaluation of a dress plan: item points from body points, built
once and called every animation frame.

:func:`dress.apply.apply` with ``penetration=False`` evaluates a plan in three
steps: the binding (one sparse product), the rigid parts (one similarity
per group) and the loose-part smoothing (one sparse solve, in the frames of
the body under each loose patch). It returns the
binding's free result too, and allocates as it goes. An animation needs only
the final points, frame after frame: :class:`FrameEvaluator` skips the
binding rows the rigid parts overwrite, writes every step into one output
array and runs the gathers and scatters as compiled loops (numba; the numpy
path is ``dress.apply.apply``'s). Same numbers as ``dress.apply.apply`` (to rounding).

Arrays are numpy; lengths in the units of the points (metres internally).
"""
from __future__ import annotations

import numpy as np

from ..dress.apply import apply
from ..kernels import HAVE_NUMBA, add_rows, binding_eval_rows, diffusion_rhs


class FrameEvaluator:
    """``FrameEvaluator(plan)(body_points (N, 3)) -> item points (M, 3)``:
    the plan's binding, rigid parts and loose-part smoothing (see
    :func:`dress.apply.apply`), for body points of the plan's body topology."""

    def __init__(self, plan):
        self.plan = plan
        b = plan.binding
        m = b.n_items
        self.n_items = m
        self.compiled = HAVE_NUMBA
        parts = plan.rigid_parts
        self._rigid = parts is not None and len(parts) > 0
        self._free_rows = np.flatnonzero(~plan.rigid_mask()).astype(np.int64)
        # the binding rows the rigid parts do not overwrite (same column layout)
        self._matrix = b.compact[self._free_rows]
        self._matrix.sort_indices()
        self.used_faces = b.used_faces
        self._buf = np.zeros((self._matrix.shape[1], 3))
        sm = plan.smoother
        self._smooth = sm.active
        if self._smooth:
            lap = sm.boundary_coupling.tocsr()
            lap.sort_indices()
            self._lap = lap
            self._rhs = np.empty((len(sm.free), 3))
            # fixed index dtypes: one compiled signature (the warm-up's)
            self._free = np.ascontiguousarray(sm.free, dtype=np.int64)
            self._boundary = np.ascontiguousarray(sm.boundary, dtype=np.int64)

    def __call__(self, body_points: np.ndarray) -> np.ndarray:
        plan = self.plan
        p = np.ascontiguousarray(body_points, dtype=np.float64)
        if not self.compiled:  # pragma: no cover - numpy path
            return apply(plan, p, None, penetration=False)[0]
        out = np.empty((self.n_items, 3))
        m = self._matrix
        binding_eval_rows(p, self.used_faces, m.indptr, m.indices, m.data, self._free_rows, self._buf, out)
        if self._rigid:
            parts = plan.rigid_parts
            parts.place(*parts.transforms(p), out)
        if self._smooth:
            sm = plan.smoother
            lap = self._lap
            ref_free, ref_boundary = sm.frame_reference(plan.ref_points, p, plan.ref_body)
            diffusion_rhs(out, self._free, self._boundary, np.ascontiguousarray(ref_free),
                          np.ascontiguousarray(ref_boundary), sm.mass, lap.indptr, lap.indices, lap.data, self._rhs)
            add_rows(out, self._free, ref_free, np.ascontiguousarray(sm.solver.solve(self._rhs)))
        return out
