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


def _far_shell():
    """A shell 4 cm off a sphere, and the body with a bump 6 cm high round
    +x: the bump comes 2 cm through the shell."""
    body = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    shell = trimesh.creation.icosphere(subdivisions=3, radius=0.34)
    bp, bf = np.asarray(body.vertices, float), np.asarray(body.faces, np.int64)
    top = np.array([0.3, 0.0, 0.0])
    d = np.linalg.norm(bp - top, axis=1)
    bump = bp + (0.06 * np.clip(1.0 - d / 0.08, 0.0, None))[:, None] * bp / 0.3
    return bp, bf, bump, np.asarray(shell.vertices, float)


@pytest.mark.parametrize("compiled", [True, False])
def test_max_clearance_caps_what_a_push_gives_back(compiled):
    # a vertex 4 cm off the body gets 4 cm back without a cap (a bulk of
    # hair pushed that far from whatever surface is nearest), 1 cm with it
    bp, bf, bump, sp_ = _far_shell()
    q = SurfaceQuery(bf, bump)
    inside = np.flatnonzero(q.signed_distance(sp_) < -0.005)
    assert len(inside) >= 1
    free, _ = PenetrationGuard(bf, bp, sp_, compiled=compiled).apply(bump, sp_)
    capped, _ = PenetrationGuard(bf, bp, sp_, compiled=compiled, max_clearance=0.01).apply(bump, sp_)
    d_free, d_capped = q.signed_distance(free)[inside], q.signed_distance(capped)[inside]
    np.testing.assert_allclose(d_free, 0.04, atol=0.004)
    np.testing.assert_allclose(d_capped, 0.01, atol=0.003)
    # vertices the bump does not reach are left alone either way
    far = np.linalg.norm(sp_ - [0.34, 0.0, 0.0], axis=1) > 0.2
    np.testing.assert_array_equal(capped[far], sp_[far])
    # a cap under the margin still keeps the margin
    g = PenetrationGuard(bf, bp, sp_, margin=0.002, max_clearance=0.0005)
    assert g.target.min() == pytest.approx(0.002)


def test_a_push_left_inside_is_redone_from_the_whole_body():
    # the frame's few candidate triangles can give a wrong normal (large
    # triangles, overlapping parts of a game body) and the push then goes
    # into the body: the check against the whole body redoes it from where
    # the vertex was, along its true closest feature's normal, to its
    # clearance; a push that was not needed at all is dropped
    body = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    bp, bf = np.asarray(body.vertices, float), np.asarray(body.faces, np.int64)
    pts = np.array([[0.31, 0.0, 0.0], [0.0, 0.33, 0.0], [0.0, 0.0, -0.35]])
    g = PenetrationGuard(bf, bp, pts, max_clearance=0.02)
    g.update(bp)
    target = g.target.copy()
    # pushes as a wrong normal gives them: inward, 2 cm and 1 cm
    g.push[:] = [0.02, 0.01, 0.0]
    g.direction[:2] = -pts[:2] / np.linalg.norm(pts[:2], axis=1, keepdims=True)
    out = pts + g.push[:, None] * g.direction
    fixed = g._checked(pts, out.copy())
    d = SurfaceQuery(bf, bp).signed_distance(fixed)
    # the first was pushed 1 cm into the body: out again, at its clearance
    assert d[0] == pytest.approx(target[0], abs=0.002)
    assert g.direction[0] @ (pts[0] / np.linalg.norm(pts[0])) > 0.95
    # the second was outside by its clearance before the push: the wrong
    # push (into the body, leaving it outside still) is dropped; before, a
    # push that ended outside stood, and on a dense body with an arm across
    # the hip it carried a waistband vertex 28 mm through the arm
    np.testing.assert_array_equal(fixed[1], pts[1])
    assert g.push[1] == 0.0
    # the third was not pushed
    np.testing.assert_array_equal(fixed[2], pts[2])
    # without the check (a dense body) the pushes stand as they are
    off = PenetrationGuard(bf, bp, pts, max_clearance=0.02, check_pushes=False)
    off.update(bp)
    off.push[:] = g.push
    np.testing.assert_array_equal(off._checked(pts, out.copy()), out)


def test_a_vertex_deep_in_a_limb_that_moved_is_checked_against_the_limb_now():
    # a waistband vertex 6 cm inside a thigh that swept up through it in a
    # fast turn: no body vertex nor triangle centre within the grids' radius,
    # and its frame-0 triangles carried half a metre away by the limb. The
    # whole-body check took its closest point among those alone and pushed
    # it 49 cm (the long skirt, CMU 131_01 at frame 82): it must find the
    # limb it is in now, and push by its depth there
    body = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    bp, bf = np.asarray(body.vertices, float), np.asarray(body.faces, np.int64)
    pts = np.array([[0.303, 0.0, 0.0]])
    g = PenetrationGuard(bf, bp, pts)
    # the body turned half round and moved: the vertex is 8 cm under the
    # skin on the far side from its frame-0 triangles
    turn = np.diag([-1.0, 1.0, -1.0])
    moved = bp @ turn.T + [0.303 - 0.22, 0.0, 0.0]
    q = SurfaceQuery(bf, moved)
    depth = -float(q.signed_distance(pts)[0])
    assert 0.05 < depth < 0.12
    g.update(moved)
    # as the frame's pass leaves it: pushed along some normal, to be checked
    g.push[:] = 0.01
    g.direction[:] = [1.0, 0.0, 0.0]
    fixed = g._checked(pts, pts + [[0.01, 0.0, 0.0]])
    # pushed out of the sphere where it is now, by its depth plus its
    # clearance, not through the far side
    assert g.push[0] == pytest.approx(depth + g.target[0], abs=0.003)
    assert q.signed_distance(fixed)[0] == pytest.approx(g.target[0], abs=0.003)


@pytest.mark.parametrize("compiled", [True, False])
def test_a_vertex_the_body_came_through_faster_than_the_radius_is_pushed_out(compiled):
    # 5 cm off the body at frame 0 (no body vertex within the guard's 3 cm:
    # its estimate is "far"), then the body moves 13 cm towards it in one
    # frame: 8 cm inside, still no body vertex within 3 cm. The frame's pass
    # takes it for far outside; it must come out to its clearance (the back
    # of a long skirt's waistband, 5-6 cm inside the buttocks in a dance)
    body = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    bp, bf = np.asarray(body.vertices, float), np.asarray(body.faces, np.int64)
    pts = np.array([[0.35, 0.0, 0.0], [0.0, 0.36, 0.0], [-0.32, 0.0, 0.0]])
    g = PenetrationGuard(bf, bp, pts, max_clearance=0.003, compiled=compiled)
    assert np.isinf(g.approx0[:2]).all()
    moved = bp + [0.13, 0.0, 0.0]
    q = SurfaceQuery(bf, moved)
    d_before = q.signed_distance(pts)
    assert d_before[0] < -0.07 and d_before[1] > 0.0 and d_before[2] > 0.0
    out, _ = g.apply(moved, pts)
    d = q.signed_distance(out)
    assert d[0] == pytest.approx(0.003, abs=0.002)
    assert out[0, 0] > pts[0, 0] + 0.07                 # out along +x, the way it came in
    # far outside (the second) and near outside (the third) are left alone
    np.testing.assert_array_equal(out[1:], pts[1:])
    # and the next frame keeps it out (its push decays from there)
    again, _ = g.apply(moved, pts)
    assert q.signed_distance(again)[0] > 0.0


@pytest.mark.parametrize("compiled", [True, False])
def test_on_a_coarse_body_the_deep_search_reaches_past_its_long_edges(compiled):
    # a 42-vertex sphere (edges 18 cm): a vertex 12 cm under its skin has no
    # body vertex within the 10 cm a dense body needs; the search reaches
    # 1.5 x the body's long edges there (RiggedFigure's box body: 57 cm)
    body = trimesh.creation.icosphere(subdivisions=1, radius=0.3)
    bp, bf = np.asarray(body.vertices, float), np.asarray(body.faces, np.int64)
    pts = np.array([[0.35, 0.0, 0.0]])
    g = PenetrationGuard(bf, bp, pts, max_clearance=0.003, compiled=compiled)
    moved = bp + [0.17, 0.0, 0.0]
    q = SurfaceQuery(bf, moved)
    assert q.signed_distance(pts)[0] < -0.1
    assert np.linalg.norm(moved - pts[0], axis=1).min() > PenetrationGuard.DEEP_REACH
    out, _ = g.apply(moved, pts)
    assert q.signed_distance(out)[0] == pytest.approx(0.003, abs=0.002)


@pytest.mark.parametrize("compiled", [True, False])
def test_vertices_named_in_also_are_guarded_though_they_start_inside(compiled):
    # a shell that starts 5 mm inside a sphere round +x (a first pose's
    # dress in the skin): left there without ``also``, pushed out to the
    # margin with it; the bump of the frame comes through the rest as before
    bp, bf, bump, sp_, sf = _scene()
    start = sp_.copy()
    sunk = np.linalg.norm(sp_ - [0.31, 0.0, 0.0], axis=1) < 0.08
    start[sunk] *= 0.295 / 0.31
    q0 = SurfaceQuery(bf, bp)
    assert np.all(q0.signed_distance(start[sunk]) < -0.004) and sunk.sum() >= 5
    plain, _ = PenetrationGuard(bf, bp, start, margin=0.001, compiled=compiled).apply(bp, start)
    also, _ = PenetrationGuard(bf, bp, start, margin=0.001, compiled=compiled, also=sunk).apply(bp, start)
    np.testing.assert_array_equal(plain[sunk], start[sunk])
    d = q0.signed_distance(also[sunk])
    np.testing.assert_allclose(d, 0.001, atol=2e-4)
    np.testing.assert_array_equal(also[~sunk], start[~sunk])
