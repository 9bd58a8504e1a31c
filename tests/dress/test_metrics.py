"""Known-answer cases for the item shape measures (metrics.shape_change)."""
from __future__ import annotations

import numpy as np
import trimesh

from wearfit_usd.dress import metrics as M
from wearfit_usd.dress.binding import bind
from wearfit_usd.dress.body_stretch import principal_stretches


def _plate():
    """A flat 10 cm body plate at z = 0 (normal +z) of 8 x 8 squares."""
    n = 9
    x, y = np.meshgrid(np.linspace(-0.05, 0.05, n), np.linspace(-0.05, 0.05, n))
    pts = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([i, i + 1, i + n + 1], 1), np.stack([i, i + n + 1, i + n], 1)])
    return pts, faces


def _shape(item, new, faces, body, fit_body, body_faces, k=3):
    b = bind(body, body_faces, item, k=k)
    return M.shape_change(item, new, faces, b.triangles, b.weights, body, fit_body, body_faces)


def test_degenerate_sliver_is_excluded_and_counted():
    """Two item triangles 5 mm over a plate that does not move: a good one
    and a 0.3-degree sliver whose apex crosses its base by 0.2 mm (a sliver's
    normal turns over for a sub-millimetre move). The sliver is left out of
    the main figure but counted, and still counted by the strict one; the
    good triangle turned over is counted by both."""
    body, bf = _plate()
    item = np.array([[0.0, 0.0, 0.005], [0.02, 0.0, 0.005], [0.0, 0.02, 0.005],          # good
                     [0.0, -0.01, 0.005], [0.02, -0.01, 0.005], [0.01, -0.01 + 0.0001 / 2, 0.005]])  # sliver
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    assert M.min_angle_deg(item, faces)[1] < 1.0 < M.min_angle_deg(item, faces)[0]
    new = item.copy()
    new[5, 1] -= 0.0002  # apex across the base
    r = _shape(item, new, faces, body, body, bf)
    assert r["degenerate"] == 1 and r["flipped_degenerate"] == 1
    assert r["flipped_pct"] == 0.0
    assert r["flipped_strict_pct"] == 50.0
    new[2] = [0.0, -0.02, 0.005]  # the good triangle folded over
    r = _shape(item, new, faces, body, body, bf)
    assert r["flipped_pct"] == 100.0 and r["flipped_strict_pct"] == 100.0 and r["degenerate"] == 1


def test_uniformly_scaled_shell_is_within_the_bodys_stretch():
    """A shell 5 cm off a 5 cm ball, the ball shrunk to half: the shell
    shrinks by (R' + c) / (R + c) = 0.75, not by the skin's 0.5. Within the
    offset-corrected range of the main figure, outside the strict one
    (0.75 > 1.25 x 0.5). A shell shrunk like the skin (0.5) passes both; a
    shell crushed to a third is over-compressed by the main figure too."""
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    body, bf = np.asarray(ball.vertices), np.asarray(ball.faces)
    shell = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    u, faces = np.asarray(shell.vertices), np.asarray(shell.faces)
    item = u * 0.10
    fit = body * 0.5
    r = _shape(item, u * (0.025 + 0.05), faces, body, fit, bf, k=5)
    assert r["overstretch_pct"] == 0.0
    assert r["overstretch_strict_pct"] > 90.0
    assert r["flipped_pct"] == 0.0 and r["degenerate"] == 0
    r = _shape(item, u * 0.05, faces, body, fit, bf, k=5)  # like the skin: ratio 0.5
    assert r["overstretch_pct"] == 0.0 and r["overstretch_strict_pct"] == 0.0
    r = _shape(item, u * 0.10 / 3, faces, body, fit, bf, k=5)  # ratio 1/3 < 0.8 x 0.5
    assert r["overstretch_pct"] == 100.0


def test_edge_range_covers_both_endpoints_bound_triangles():
    """An item edge over two body triangles, one stretched by 1.4 along the
    edge, the other not: the edge stretched 1.6 x is within 1.25 x the
    neighbourhood's range (both endpoints' triangles), but outside the
    strict single triangle of its first vertex (the unstretched one)."""
    body = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0.02, 0, 0], [0.02, 0.01, 0]], float)
    bf = np.array([[0, 1, 2], [1, 3, 4]])
    fit = body.copy()
    fit[3, 0] = 0.01 + 0.01 * 1.4
    fit[4, 0] = 0.01 + 0.01 * 1.4
    item = np.array([[0.002, 0.002, 0.001], [0.018, 0.002, 0.001], [0.003, 0.006, 0.001]])
    faces = np.array([[0, 1, 2]])
    new = item.copy()
    new[1, 0] = item[0, 0] + 0.016 * 1.6
    b = bind(body, bf, item, k=1)
    assert b.triangles[0, 0] == 0 and b.triangles[1, 0] == 1
    r = M.shape_change(item, new, faces, b.triangles, b.weights, body, fit, bf)
    e = np.flatnonzero(r["overstretched"] == 0)  # edge (0, 1) is the first of redress.edges
    assert len(e) == 0
    assert r["overstretch_strict_pct"] > 0.0


def test_real_female_thin_ponytail(ref_female, usd_dir):
    """The thin female body's ponytail (the last item with flipped triangles
    by the strict figure: three hair-card slivers at 92-97 degrees): no
    flipped triangle by the main figure, its 52 degenerate reference
    triangles counted, at most the strict 0.056 %."""
    from wearfit_usd.dress.apply import dress
    from wearfit_usd.io.usd import read_character
    tgt = read_character(usd_dir / "body_female_thin.usdc")
    rows = {r["item"]: r for r in M.dress_report(ref_female, tgt, dress(ref_female, tgt))}
    pony = rows["ponytail01"]
    assert pony["degenerate"] == 52
    assert pony["flipped_pct"] == 0.0 and pony["flipped_strict_pct"] <= 0.06
    for r in rows.values():
        assert r["flipped_pct"] == 0.0 and r["overstretch_pct"] <= 0.5, r
        assert r["new_pen_pct"] <= 0.5 and r["clear_med_mm"] <= 2.0 and r["clear_p95_mm"] <= 10.0, r


def _box(lo, hi):
    """A closed box item (8 corners, 12 triangles, 18 edges)."""
    box = trimesh.creation.box(bounds=[lo, hi])
    return np.asarray(box.vertices, float), np.asarray(box.faces, np.int64)


def test_rigid_part_judged_by_its_own_uniform_scale():
    """A box 5 mm over a plate that does not move, moved by a pure
    similarity (scale 1.3, a turn, a shift): every edge grows 1.3 x, beyond
    1.25 x the body's stretch (1), so as a free item all 18 edges are
    over-stretched; as a rigid group they keep their shape up to the fitted
    scale: none beyond the rigid criterion, residual 0, and none left in the
    free figure. The same box with one corner pushed 6 mm off the similarity
    (a per-vertex correction bending the rigid part) is caught by the rigid
    criterion, with that residual."""
    body, bf = _plate()
    item, faces = _box([-0.01, -0.01, 0.005], [0.01, 0.01, 0.015])
    a = np.radians(20)
    rot = np.array([[np.cos(a), np.sin(a), 0], [-np.sin(a), np.cos(a), 0], [0, 0, 1]])
    new = 1.3 * item @ rot + [0.001, 0.002, 0.0]
    b = bind(body, bf, item, k=3)
    args = (item, new, faces, b.triangles, b.weights, body, body, bf)
    free = M.shape_change(*args)
    assert free["overstretch_pct"] == 100.0 and free["rigid_edges"] == 0
    r = M.shape_change(*args, rigid_groups=[np.arange(8)])
    assert r["rigid_edges"] == 18 and r["overstretch_rigid_pct"] == 0.0
    assert r["overstretch_pct"] == 0.0 and len(r["overstretched"]) == 0
    assert r["rigid_residual_mm"] < 1e-9
    assert r["overstretch_strict_pct"] == 100.0  # the strict figure still counts every edge
    bent = new.copy()
    top = np.flatnonzero(item[:, 2] > 0.01)
    bent[top[0]] -= 0.006 * np.array([0, 0, 1.0])   # 6 mm down: its vertical edges 13 -> 7 mm (0.54 x)
    r = M.shape_change(item, bent, faces, b.triangles, b.weights, body, body, bf, rigid_groups=[np.arange(8)])
    assert r["overstretch_rigid_pct"] > 0.0 and len(r["overstretched_rigid"]) >= 1
    assert 3.0 < r["rigid_residual_mm"] < 6.0


def test_rigid_and_free_edges_counted_apart():
    """Two boxes in one item, the first rigid, the second free and both
    moved by the same 1.3 x similarity: the free box's 18 edges are the only
    ones in the free figure (100 % of the free edges), the rigid box's 18
    are counted apart and pass."""
    body, bf = _plate()
    b1, f1 = _box([-0.03, -0.01, 0.005], [-0.01, 0.01, 0.015])
    b2, f2 = _box([0.01, -0.01, 0.005], [0.03, 0.01, 0.015])
    item, faces = np.concatenate([b1, b2]), np.concatenate([f1, f2 + 8])
    new = 1.3 * item
    b = bind(body, bf, item, k=3)
    r = M.shape_change(item, new, faces, b.triangles, b.weights, body, body, bf, rigid_groups=[np.arange(8)])
    assert r["rigid_edges"] == 18 and r["overstretch_rigid_pct"] == 0.0
    assert r["overstretch_pct"] == 100.0 and len(r["overstretched"]) == 18


def test_principal_stretches_of_a_known_map():
    """A stretch by 2 along (1, -1) (and 1 across): the principal stretches
    are (1, 2) on every triangle, although no triangle edge of the plate
    (along x, y and (1, 1)) stretches by more than 1.58."""
    body, bf = _plate()
    u = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    a = np.eye(3) + np.outer(u, u)
    lo, hi = principal_stretches(body, body @ a.T, bf)
    np.testing.assert_allclose(lo, 1.0, atol=1e-12)
    np.testing.assert_allclose(hi, 2.0, atol=1e-12)
    e = np.concatenate([bf[:, [0, 1]], bf[:, [1, 2]], bf[:, [2, 0]]])
    d = body[e[:, 1]] - body[e[:, 0]]
    assert (np.linalg.norm(d @ a.T, axis=1) / np.linalg.norm(d, axis=1)).max() < 1.6
    # a degenerate reference triangle gets (1, 1)
    lo, hi = principal_stretches(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]), np.eye(3), np.array([[0, 1, 2]]))
    assert lo[0] == 1.0 and hi[0] == 1.0


def test_item_edge_along_the_skins_greatest_stretch_is_within_it():
    """An item triangle 5 mm over the plate with an edge along (1, -1), the
    direction the plate stretches by 2: carried by the same map, that edge
    stretches by 2, more than 1.25 x any plate edge's ratio (1.58) but
    within the plate's own stretch, so it is not flagged; stretched by 2.6
    (beyond 1.25 x 2) it is."""
    body, bf = _plate()
    u = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    a = np.eye(3) + np.outer(u, u)
    item = np.array([[-0.01, 0.01, 0.005], [0.01, -0.01, 0.005], [0.01, 0.01, 0.005]])
    faces = np.array([[0, 1, 2]])
    new = item @ a.T
    r = _shape(item, new, faces, body, body @ a.T, bf)
    assert r["overstretch_pct"] == 0.0 and r["flipped_pct"] == 0.0
    far = new.copy()
    far[1] = far[0] + 1.3 * (new[1] - new[0])  # the (1, -1) edge at 2.6 x
    r = _shape(item, far, faces, body, body @ a.T, bf)
    e = np.flatnonzero(r["overstretched"] == 0)  # edge (0, 1) is the first of redress.edges
    assert len(e) == 1
