"""The per-frame penetration guard: pushes spread over the item's edges.

Known answers on a shell around a sphere whose body grows a bump through it:
the vertices the bump reaches are pushed out as far as without spreading,
their neighbours follow part of the way (the edges round the bump stretch
less), vertices far from it do not move.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from wearfit_usd.animate.penetration_guard import PenetrationGuard
from wearfit_usd.geometry.closest import SurfaceQuery
from wearfit_usd.geometry.mesh import adjacency, edges


def _scene():
    body = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    shell = trimesh.creation.icosphere(subdivisions=3, radius=0.31)
    bp, bf = np.asarray(body.vertices, float), np.asarray(body.faces, np.int64)
    sp_, sf = np.asarray(shell.vertices, float), np.asarray(shell.faces, np.int64)
    # the frame: a bump 2.5 cm high on the body round +x (the vertices within 6 cm of it)
    top = np.array([0.3, 0.0, 0.0])
    d = np.linalg.norm(bp - top, axis=1)
    bump = bp + (0.025 * np.clip(1.0 - d / 0.06, 0.0, None))[:, None] * bp / 0.3
    return bp, bf, bump, sp_, sf


def _stretch(p0, p1, e):
    l0 = np.linalg.norm(p0[e[:, 0]] - p0[e[:, 1]], axis=1)
    return np.linalg.norm(p1[e[:, 0]] - p1[e[:, 1]], axis=1) / l0


def test_pushes_spread_over_the_item_edges():
    bp, bf, bump, sp_, sf = _scene()
    e = edges(sf)
    plain = PenetrationGuard(bf, bp, sp_, margin=0.001)
    spread = PenetrationGuard(bf, bp, sp_, margin=0.001, item_neighbours=adjacency(sf, len(sp_)))
    out0, _ = plain.apply(bump, sp_)
    out1, _ = spread.apply(bump, sp_)
    q = SurfaceQuery(bf, bump)
    d_before, d0, d1 = q.signed_distance(sp_), q.signed_distance(out0), q.signed_distance(out1)
    pushed = np.flatnonzero(np.linalg.norm(out0 - sp_, axis=1) > 1e-6)
    assert len(pushed) >= 3 and d_before[pushed].min() < 0.0  # the bump came through the shell
    # the pushed vertices are out as far as without spreading (their push kept)
    assert np.all(d1[pushed] >= d0[pushed] - 1e-6)
    assert np.all(d1[pushed] > 0.0)
    # their neighbours follow part of the way: the edges round the bump stretch less
    s0, s1 = _stretch(sp_, out0, e), _stretch(sp_, out1, e)
    assert s1.max() < s0.max() - 0.05, (s0.max(), s1.max())
    moved1 = np.linalg.norm(out1 - sp_, axis=1) > 1e-6
    assert moved1.sum() > len(pushed)
    # far from the bump nothing moves
    far = np.linalg.norm(sp_ - [0.31, 0.0, 0.0], axis=1) > 0.25
    np.testing.assert_array_equal(out1[far], sp_[far])


def test_without_edges_the_guard_is_unchanged():
    bp, bf, bump, sp_, sf = _scene()
    a, _ = PenetrationGuard(bf, bp, sp_).apply(bump, sp_)
    b, _ = PenetrationGuard(bf, bp, sp_, item_neighbours=sp.csr_matrix((len(sp_), len(sp_)))).apply(bump, sp_)
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="item_neighbours"):
        PenetrationGuard(bf, bp, sp_, item_neighbours=adjacency(sf, len(sp_))[:10, :10])
