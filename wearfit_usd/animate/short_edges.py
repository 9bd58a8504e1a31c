"""Item vertices joined by very short edges, kept together in every frame.

Two item vertices a fraction of a millimetre apart (the pole of a hair mesh,
the seam where a top's hem meets the hot pants in one mesh) are moved by
whatever moves each: their own bound triangles, the loose smoothing, the
penetration guard's pushes, a rigid piece's hinge. Where those differ the
edge between them opens by millimetres, a crack in the item and tens of
times the skin's stretch (``bob01``'s 0.2 mm edge at 5.9 mm in the Daz
walk, 29x; ``female_casualsuit02``'s 0.8 mm edge at 20 mm in the
pirouette, 17x).

:class:`ShortEdgeWeld` is built once on the items as authored: the
connected groups of item edges shorter than ``length``. Each frame no member
of a group lies farther from the group's centre than it does at rest:

    c_g = mean_g(x),   r_v = |x0_v - mean_g(x0)|,
    x_v <- c_g + (x_v - c_g) * min(1, r_v / |x_v - c_g|)   for v in group g,

so a group keeps the orientation the frame gives it (no rest offsets turned
the wrong way on a turning head) and cannot open wider than at rest (a
two-vertex group's edge keeps at most its rest length); a group that is not
stretched is not moved. A group wider than ``2 length`` from its centre (a
chain of short edges along a hair strand) is left alone.

Arrays are numpy; metres.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

WELD_LENGTH = 0.0015  # m: edges shorter than this hold their vertices together


class ShortEdgeWeld:
    """``weld(points (M, 3)) -> points`` (in place): the members of each
    group of item vertices joined by edges shorter than ``length`` kept
    within their rest distance of the group's centre (module docstring).

    Parameters
    ----------
    points0 : (M, 3) the items at rest (as authored).
    edges : (E, 2) int, the items' edges.
    length : m.
    """

    def __init__(self, points0: np.ndarray, edges: np.ndarray, length: float = WELD_LENGTH):
        q = np.asarray(points0, dtype=np.float64)
        e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        if q.ndim != 2 or q.shape[1] != 3:
            raise ValueError(f"points0 must be (M, 3), not {q.shape}")
        if len(e) and (e.min() < 0 or e.max() >= len(q)):
            raise ValueError(f"edges index {len(q)} points out of range")
        if length <= 0:
            raise ValueError(f"length must be > 0, not {length}")
        m = len(q)
        short = e[np.linalg.norm(q[e[:, 0]] - q[e[:, 1]], axis=1) < length] if len(e) else e
        self.rows = np.zeros(0, dtype=np.int64)
        self.group = np.zeros(0, dtype=np.int64)
        self.reach = np.zeros(0)
        self.n_groups = 0
        if len(short) == 0:
            return
        g = sp.csr_matrix((np.ones(len(short)), (short[:, 0], short[:, 1])), shape=(m, m))
        _, comp = connected_components(g, directed=False)
        size = np.bincount(comp)
        rows = np.flatnonzero(size[comp] >= 2)
        _, group = np.unique(comp[rows], return_inverse=True)
        n = int(group.max()) + 1
        cnt = np.bincount(group, minlength=n).astype(np.float64)
        mean0 = np.zeros((n, 3))
        np.add.at(mean0, group, q[rows])
        mean0 /= cnt[:, None]
        off = q[rows] - mean0[group]
        # groups reaching farther than 2 length from their mean are chains: left alone
        wide = np.zeros(n, dtype=bool)
        np.logical_or.at(wide, group, np.linalg.norm(off, axis=1) > 2.0 * length)
        keep = ~wide[group]
        rows, group, off = rows[keep], group[keep], off[keep]
        if len(rows) == 0:
            return
        _, group = np.unique(group, return_inverse=True)
        self.n_groups = int(group.max()) + 1
        self.rows, self.group = rows, group
        self.reach = np.linalg.norm(off, axis=1)  # rest distance of each member from its centre
        cnt = np.bincount(group).astype(np.float64)
        self._mean = sp.csr_matrix((1.0 / cnt[group], (group, rows)), shape=(self.n_groups, m))

    def __len__(self) -> int:
        return len(self.rows)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        if len(self.rows) == 0:
            return points
        c = (self._mean @ points)[self.group]
        d = points[self.rows] - c
        r = np.linalg.norm(d, axis=1)
        f = np.minimum(1.0, self.reach / np.maximum(r, 1e-300))
        points[self.rows] = c + d * f[:, None]
        return points
