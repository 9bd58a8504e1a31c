"""Item parts that move as a whole (shoe soles, hat brims, glasses...).

Each group of item vertices follows the best-fit similarity (Umeyama) of the
body patch it is bound to, from the reference body to the current one. Built
once (:class:`RigidParts`), evaluated per frame: the per-group 3x3 cross
covariances of all groups are one sparse product, the SVDs one batched call.
Arrays are numpy; lengths in the units of the points.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..kernels import similarity_place, similarity_transforms


class RigidParts:
    """groups: list of (item vertex indices (P,), body vertex indices (Q,),
    body vertex weights (Q,)); ref_body (N, 3) the body the items were bound
    on; ref_points (M, 3) the items there. ``scale``: similarity (uniform
    scale) rather than rigid motion.

    ``parts(body_points (N, 3), points (M, 3))`` writes the moved groups into
    ``points`` (in place) and returns it.
    """

    def __init__(self, groups: list, ref_body: np.ndarray, ref_points: np.ndarray, scale: bool = True):
        self.scale = scale
        self.groups = [np.asarray(gv, dtype=np.int64) for gv, _, _ in groups]
        self.ref_points = [np.ascontiguousarray(ref_points[gv]) for gv in self.groups]
        # all groups' vertices in one run for the compiled placement
        self._rows = np.concatenate(self.groups) if self.groups else np.zeros(0, dtype=np.int64)
        self._group = np.repeat(np.arange(len(self.groups)), [len(gv) for gv in self.groups])
        self._ref_all = (np.ascontiguousarray(np.concatenate(self.ref_points), dtype=np.float64)
                         if self.groups else np.zeros((0, 3)))
        n_body = len(ref_body)
        g = len(groups)
        self._mean = None
        if g == 0:
            return
        rows_m, rows_h, cols, vals_m, vals_h = [], [], [], [], []
        self._src_mean = np.zeros((g, 3))
        self._src_var = np.zeros(g)
        for i, (_, bv, bw) in enumerate(groups):
            bv = np.asarray(bv, dtype=np.int64)
            w = np.asarray(bw, dtype=np.float64)
            w = w / w.sum()
            ms = w @ ref_body[bv]
            a = ref_body[bv] - ms
            self._src_mean[i] = ms
            self._src_var[i] = w @ np.einsum("ij,ij->i", a, a)
            rows_m.append(np.full(len(bv), i))
            cols.append(bv)
            vals_m.append(w)
            # rows 3 i + c of the cross-covariance operator: sum_j w_j a_jc dst_j
            rows_h.append(3 * i + np.arange(3)[:, None] + np.zeros((1, len(bv)), dtype=np.int64))
            vals_h.append((a * w[:, None]).T)
        self._mean = sp.csr_matrix((np.concatenate(vals_m), (np.concatenate(rows_m), np.concatenate(cols))),
                                   shape=(g, n_body))
        self._cov = sp.csr_matrix((np.concatenate([v.ravel() for v in vals_h]),
                                   (np.concatenate([r.ravel() for r in rows_h]),
                                    np.concatenate([np.tile(c, 3) for c in cols]))),
                                  shape=(3 * g, n_body))

    def __len__(self) -> int:
        return len(self.groups)

    def transforms(self, body_points: np.ndarray):
        """Per group: scale (G,), row-vector rotation (G, 3, 3) and
        translation (G, 3) with dst ~ s * src @ rot + t."""
        # compiled: one pass (the numpy calls cost ~0.2 ms a frame)
        return similarity_transforms(body_points, self._mean, self._cov, self._src_mean, self._src_var, self.scale)

    def place(self, s: np.ndarray, rot: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Write the groups moved by :meth:`transforms`' output into
        ``points`` (M, 3, C-contiguous float64 for the compiled path), in
        place; returns it."""
        return similarity_place(self._ref_all, self._rows, self._group, s, rot, t, points)

    def __call__(self, body_points: np.ndarray, points: np.ndarray) -> np.ndarray:
        if self._mean is None:
            return points
        return self.place(*self.transforms(np.asarray(body_points, dtype=np.float64)), points)
