"""Skirt parts held on the skin they touch: the contact the binding cannot keep.

A skirt's parts are bound to hip triangles that the legs do not move
(:func:`dress.plan.bind_items`), so spreading the legs neither tears nor
swings them. Where the skirt lies on a part the legs do move (the buttocks,
the sides of the hips below the iliac crest) its binding frames sit
centimetres above the skin under it, and when the hips flex the skin moves
away from those frames: in a forward bend the long skirt's back stood 5 cm
off the buttocks (CMU punch and jump: separation p95 50-51 mm), the hot
pants showing over it. A fitted skirt does not do that: the waistband's
tension holds it on the hips.

:class:`ContactHold` is built once on the static dress (``animate`` gives
it the items dressed on the target's bind pose, as the motion measures
judge them: a first pose's dress can stand off already): the skirt-part
vertices that touch the body there (signed clearance ``c0`` below
``contact``) and, for each, the skin patch under it (the body triangles
whose centroid lies within ``patch`` of its closest body point; the patch
moves with the body, so a vertex is held on the skin it lay on, not on
whatever part of the body comes nearest). Each frame a held vertex farther
from its patch than ``c0`` is pulled back along the direction to its
closest patch point:

    d = |x - p(x)|,   x <- x - min(d - c0, max_pull) (x - p(x)) / d   where d > c0,

and the pulls are spread over the held rows' neighbours (``neighbours``:
Jacobi steps, half own, half the neighbours' average; each held vertex
keeps at least its own pull), so no held vertex stands out of the skirt
around it. Vertices closer than ``c0`` or inside are left to the
penetration guard, which runs after the hold.

Arrays are numpy; metres.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..geometry.closest import SurfaceQuery

HOLD_CONTACT = 0.01   # m: vertices this close to the body in the static dress (or inside) are held
HOLD_PATCH = 0.06     # m: the skin patch a held vertex is held on (around its static closest point)
HOLD_MAX_PULL = 0.10  # m: the largest pull in one frame
HOLD_SPREAD = 2       # Jacobi steps spreading the pulls over the neighbours


class ContactHold:
    """``hold(body_points (N, 3), points (M, 3)) -> points (M, 3)``: the
    held vertices among ``rows`` pulled back onto their skin patch (module
    docstring). A copy; the rows not held (and not spread to) unchanged.

    Parameters
    ----------
    faces : (T, 3) int, the body's triangles.
    body0 : (N, 3) the body of the static dress.
    points0 : (M, 3) the items dressed on it.
    rows : (R,) int, the candidate rows (skirt parts that the binding moves
        directly, not the cloth); those within ``contact`` of the body are held.
    neighbours : (M, M) sparse, the items' vertex adjacency (or None: no spread).
    contact, patch, max_pull : m.
    spread : int, Jacobi steps.
    """

    def __init__(self, faces: np.ndarray, body0: np.ndarray, points0: np.ndarray, rows: np.ndarray,
                 neighbours: sp.spmatrix | None = None, contact: float = HOLD_CONTACT, patch: float = HOLD_PATCH,
                 max_pull: float = HOLD_MAX_PULL, spread: int = HOLD_SPREAD):
        faces = np.asarray(faces, dtype=np.int64)
        body0 = np.asarray(body0, dtype=np.float64)
        p0 = np.asarray(points0, dtype=np.float64)
        rows = np.unique(np.asarray(rows, dtype=np.int64).ravel())
        if p0.ndim != 2 or p0.shape[1] != 3:
            raise ValueError(f"points0 must be (M, 3), not {p0.shape}")
        if len(rows) and (rows[0] < 0 or rows[-1] >= len(p0)):
            raise ValueError(f"rows index outside the {len(p0)} item points")
        if not (contact > 0 and patch > 0 and max_pull > 0 and spread >= 0):
            raise ValueError("contact, patch and max_pull must be > 0 and spread >= 0")
        self.max_pull = float(max_pull)
        self.query = SurfaceQuery(faces, body0)
        self.held = np.zeros(0, dtype=np.int64)
        if len(rows) == 0:
            return
        foot = self.query.closest(p0[rows])
        touch = foot["distance"] < contact
        self.held = rows[touch]
        if len(self.held) == 0:
            return
        self.c0 = np.maximum(foot["distance"][touch], 0.0)
        # the skin patch under each held vertex, padded with its closest triangle
        near = self.query.centroid_tree.query_ball_point(foot["point"][touch], r=patch)
        width = max(max(len(n) for n in near), 1)
        cand = np.repeat(foot["triangle"][touch][:, None], width, axis=1)
        for i, n in enumerate(near):  # once, at build time
            cand[i, :len(n)] = n
        self.candidates = cand
        # the spread: over the candidate rows' own adjacency
        self.rows = rows
        self._walk = None
        self._steps = int(spread)
        if neighbours is not None and self._steps:
            a = sp.csr_matrix(neighbours)[rows][:, rows]
            a.data[:] = 1.0
            deg = np.asarray(a.sum(axis=1)).ravel()
            deg[deg <= 0] = 1.0
            self._walk = (sp.diags(1.0 / deg) @ a).tocsr()
            self._held_local = np.searchsorted(rows, self.held)

    @property
    def active(self) -> bool:
        """Whether any vertex is held."""
        return len(self.held) > 0

    def pulls(self, body_points: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(H, 3) the pull of each held vertex this frame (zero where it is no
        farther from its patch than in the static dress)."""
        self.query.update(np.asarray(body_points, dtype=np.float64))
        x = np.asarray(points, dtype=np.float64)[self.held]
        res = self.query.closest(x, candidates=self.candidates, ring=False)
        away = x - res["point"]
        d = np.linalg.norm(away, axis=1)
        out = (res["distance"] > 0.0) & (d > self.c0 + 1e-6)
        pull = np.zeros_like(x)
        amount = np.minimum(d[out] - self.c0[out], self.max_pull)
        pull[out] = -(amount / d[out])[:, None] * away[out]
        return pull

    def __call__(self, body_points: np.ndarray, points: np.ndarray) -> np.ndarray:
        out = np.array(points, dtype=np.float64, copy=True)
        if not self.active:
            return out
        pull = self.pulls(body_points, out)
        if not np.any(pull):
            return out
        if self._walk is None:
            out[self.held] += pull
            return out
        # spread over the candidate rows; each held vertex keeps its own pull
        d = np.zeros((len(self.rows), 3))
        h = self._held_local
        d[h] = pull
        n0 = np.linalg.norm(pull, axis=1)
        u = pull / np.maximum(n0, 1e-12)[:, None]
        for _ in range(self._steps):
            d = 0.5 * d + 0.5 * (self._walk @ d)
            short = n0 - np.einsum("ij,ij->i", d[h], u)
            d[h] += np.maximum(short, 0.0)[:, None] * u
        out[self.rows] += d
        return out
