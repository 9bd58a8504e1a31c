"""Strain limiting of animated items (animate.strain_limit)."""
from __future__ import annotations

import numpy as np
import pytest

from wearfit_usd.animate.short_edges import ShortEdgeWeld
from wearfit_usd.animate.strain_limit import NEAR_SKIN, StrainLimit
from wearfit_usd.geometry.mesh import edges as mesh_edges
from wearfit_usd.kernels import HAVE_NUMBA, wavefront_levels, weld_groups


def plane(n=21, size=0.4):
    """A flat body: n x n grid over [-size/2, size/2]^2 in xz at y = 0, normals +y."""
    u = np.linspace(-size / 2, size / 2, n)
    gx, gz = np.meshgrid(u, u, indexing="ij")
    pts = np.stack([gx.ravel(), np.zeros(gx.size), gz.ravel()], axis=1)
    a = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + n], 1), np.stack([a + 1, a + n + 1, a + n], 1)])
    return pts, faces.astype(np.int64)


def sheet(n=6, size=0.05, y=0.01):
    """An item sheet 5 cm wide, 1 cm over the plane."""
    u = np.linspace(-size / 2, size / 2, n)
    gx, gz = np.meshgrid(u, u, indexing="ij")
    pts = np.stack([gx.ravel(), np.full(gx.size, y), gz.ravel()], axis=1)
    a = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + n], 1), np.stack([a + 1, a + n + 1, a + n], 1)])
    return pts, mesh_edges(faces.astype(np.int64))


def ratios(p, q, e):
    return np.linalg.norm(p[e[:, 1]] - p[e[:, 0]], axis=1) / np.linalg.norm(q[e[:, 1]] - q[e[:, 0]], axis=1)


def test_a_torn_vertex_is_pulled_back_within_the_limit():
    body, faces = plane()
    q, e = sheet()
    lim = StrainLimit(q, e, faces, body, np.ones(len(q), dtype=bool), limit=1.1, iterations=50)
    p = q.copy()
    p[14] += [0.0, 0.02, 0.0]           # one vertex 2 cm out of the sheet: its edges ~2.5x
    assert ratios(p, q, e).max() > 2.0
    out = lim(body, p.copy())
    assert ratios(out, q, e).max() < 1.1 + 1e-3
    # on the skin (1.5 mm over it) the neighbours are lifted, no vertex pulled under 1 mm
    q2, _ = sheet(y=0.0015)
    lim2 = StrainLimit(q2, e, faces, body, np.ones(len(q2), dtype=bool), limit=1.1, iterations=50)
    p2 = q2.copy()
    p2[14] += [0.0, 0.02, 0.0]
    p2[15] -= [0.0, 0.001, 0.0]        # its neighbour pressed to 0.5 mm: nothing pulls it further in
    out2 = lim2(body, p2.copy())
    assert out2[:, 1].min() >= 0.0005 - 1e-12
    assert out2[np.arange(len(q2)) != 15, 1].min() >= 0.001 - 1e-12
    assert ratios(out2, q2, e).max() < ratios(p2, q2, e).max()
    # untouched sheet, moved rigidly: nothing to do
    shifted = q + [0.01, 0.0, 0.0]
    np.testing.assert_array_equal(lim(body, shifted.copy()), shifted)


def test_the_body_s_own_stretch_is_allowed():
    """Known answer: the body stretched 1.4x along x carries the sheet
    stretched 1.4x along x: every edge within limit x hi, none moved."""
    body, faces = plane()
    q, e = sheet()
    lim = StrainLimit(q, e, faces, body, np.ones(len(q), dtype=bool), limit=1.1)
    body1 = body * [1.4, 1.0, 1.0]
    p = q * [1.4, 1.0, 1.0]
    np.testing.assert_array_equal(lim(body1, p.copy()), p)
    # the same stretch on an unstretched body is cut back
    out = lim(body, p.copy())
    assert ratios(out, q, e).max() < ratios(p, q, e).max()


def test_fixed_and_heavy_vertices():
    body, faces = plane()
    q, e = sheet()
    movable = np.ones(len(q), dtype=bool)
    movable[:6] = False                  # the first row: a rigid part
    lim = StrainLimit(q, e, faces, body, movable, limit=1.1, iterations=20)
    p = q.copy()
    p[:6] += [0.0, 0.0, -0.02]           # the rigid row moved 2 cm away
    out = lim(body, p.copy())
    np.testing.assert_array_equal(out[:6], p[:6])
    assert np.linalg.norm(out[6:12] - p[6:12], axis=1).min() > 1e-3   # the next row follows it
    # a pushed (heavy) vertex moves less than a light one, its neighbours more
    # (the edge pass shares a correction 1 : HEAVY; over the passes the
    # neighbours hand part of theirs back: 24.0 vs 26.8 mm after 20)
    p = q.copy()
    p[20] += [0.03, 0.0, 0.0]
    pushed = np.zeros(len(q), dtype=bool)
    pushed[20] = True
    nb = [14, 19, 21, 26]
    for its in (1, None):
        out = lim(body, p.copy(), pushed, iterations=its)
        light = lim(body, p.copy(), iterations=its)
        assert np.linalg.norm(out[20] - p[20]) < (0.6 if its == 1 else 0.95) * np.linalg.norm(light[20] - p[20])
        assert np.linalg.norm(out[nb] - p[nb], axis=1).mean() > 2.0 * np.linalg.norm(light[nb] - p[nb], axis=1).mean()


def test_bad_input():
    body, faces = plane()
    q, e = sheet()
    with pytest.raises(ValueError, match="out of range"):
        StrainLimit(q, e + len(q), faces, body, np.ones(len(q), dtype=bool))
    with pytest.raises(ValueError, match="limit"):
        StrainLimit(q, e, faces, body, np.ones(len(q), dtype=bool), limit=0.9)
    with pytest.raises(ValueError, match="movable"):
        StrainLimit(q, e, faces, body, np.ones(3, dtype=bool))


@pytest.mark.parametrize("compiled", [False, True] if HAVE_NUMBA else [False])
def test_a_plane_of_the_frame_is_a_floor_too(compiled):
    """Known answer: a sheet 1 cm over the plane body, one vertex pulled 2
    cm down through it (its edges torn). Without floors its neighbours are
    pulled down towards it as far as the static skin allows (1 mm over the
    plane); with a floor plane at y = 9 mm (the cloth's skin under them this
    frame) none goes below it, and the torn vertex only rises."""
    body, faces = plane()
    q, e = sheet()
    p = q.copy()
    p[14] -= [0.0, 0.02, 0.0]
    planes = np.zeros((len(q), 6))
    planes[:, 1] = 0.009
    planes[:, 4] = 1.0                                  # every vertex: floor y = 9 mm, normal +y
    lim = StrainLimit(q, e, faces, body, np.ones(len(q), dtype=bool), limit=1.1, iterations=50, compiled=compiled)
    free = lim(body, p.copy())
    held = lim(body, p.copy(), planes=planes)
    rest = np.arange(len(q)) != 14
    assert free[rest, 1].min() < 0.009 - 1e-3           # without: neighbours pulled below 8 mm
    assert held[rest, 1].min() >= 0.009 - 1e-12         # with: none below the floor
    assert held[14, 1] >= p[14, 1]
    assert ratios(held, q, e).max() < ratios(p, q, e).max()
    # a zero row is no floor: the same points as without planes
    np.testing.assert_array_equal(lim(body, p.copy(), planes=np.zeros((len(q), 6))), free)


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed: the numpy path is the only one")
def test_numba_kernel_matches_numpy_twin():
    """The compiled pass and the numpy passes agree on a torn, pushed,
    partly fixed sheet over a stretched and bent body."""
    body, faces = plane()
    q, e = sheet(y=0.004)
    rng = np.random.default_rng(3)
    movable = rng.random(len(q)) > 0.1
    bent = body * [1.25, 1.0, 0.9]
    bent[:, 1] += 0.3 * bent[:, 0] ** 2
    p = q + rng.normal(0.0, 0.004, q.shape)
    p[:, 1] += 0.3 * p[:, 0] ** 2
    pushed = rng.random(len(q)) > 0.7
    # and a floor plane of the frame under part of it (a zero row: none)
    planes = np.zeros((len(q), 6))
    under = rng.random(len(q)) > 0.5
    planes[under, 3:] = rng.normal(0.0, 0.2, (under.sum(), 3)) + [0.0, 1.0, 0.0]
    planes[under, 3:] /= np.linalg.norm(planes[under, 3:], axis=1, keepdims=True)
    planes[under, :3] = p[under] - 0.001 * planes[under, 3:]
    # and a weld of two short neighbour pairs and a triple (0 fixed: the weld moves it anyway). A tie (an
    # edge a pass brought exactly to its bound) may round either way in the two paths; here none does
    close = q.copy()
    close[[1, 8, 9, 27]] = close[[0, 7, 7, 26]] + [0.0003, 0.0, 0.0002]
    weld = ShortEdgeWeld(close, e)
    assert weld.n_groups == 3 and len(weld) == 7 and not movable[0]
    out = {}
    for compiled in (False, True):
        for floor in (None, planes):
            for grouped in (False, True):
                lim = StrainLimit(q, e, faces, body, movable, limit=1.1, iterations=6, compiled=compiled,
                                  weld=weld if grouped else None)
                out[compiled, floor is None, grouped] = lim(bent, np.ascontiguousarray(p.copy()), pushed,
                                                            planes=floor)
                assert lim.stats["edges_limited"] > 0
    assert not np.allclose(out[False, True, False], p)
    assert not np.allclose(out[False, False, False], out[False, True, False])
    assert not np.allclose(out[False, True, True], out[False, True, False])
    for key in out:
        if key[0]:
            np.testing.assert_allclose(out[key], out[(False,) + key[1:]], atol=1e-12)


def _line_gauss_seidel(x, fixed, rest, limit, passes):
    """Reference: the strain limit's passes on a line of vertices at x (n,)
    with edges (k, k + 1), written out one edge at a time (ascending on
    even passes, descending on odd ones); no body in reach."""
    x = list(x)
    for it in range(passes):
        for k in (range(len(x) - 1) if it % 2 == 0 else range(len(x) - 2, -1, -1)):
            ln, cap = x[k + 1] - x[k], limit * rest[k]
            if ln <= cap:
                continue
            wa, wb = (0.0 if fixed[k] else 1.0), (0.0 if fixed[k + 1] else 1.0)
            x[k] += (ln - cap) * wa / (wa + wb)
            x[k + 1] -= (ln - cap) * wb / (wa + wb)
    return np.array(x)


@pytest.mark.parametrize("compiled", [False, True] if HAVE_NUMBA else [False])
def test_passes_are_gauss_seidel_forward_then_back(compiled):
    """Known answer on a line of 12 vertices 1 cm over the plane, 0 fixed
    and pulled 5 cm away: each pass moves an edge's ends at once, the next
    edge sees them (one pass carries the pull down the whole line; the mean
    of a vertex's corrections, Jacobi, carried it one edge per pass), and
    the passes go forward and back in turn, as the one-edge-at-a-time loop
    written out in the test does. The first pass halves the pull at each
    edge down the line: 25, 12.5, 6.25 ... mm."""
    body, faces = plane()
    x = np.linspace(-0.055, 0.055, 12)
    q = np.stack([x, np.full(12, 0.01), np.zeros(12)], axis=1)
    e = np.stack([np.arange(11), np.arange(1, 12)], axis=1)
    movable = np.arange(12) > 0
    p = q.copy()
    p[0, 0] -= 0.05
    rest = np.diff(x)
    for passes in (1, 2, 3):
        out = StrainLimit(q, e, faces, body, movable, iterations=passes, compiled=compiled)(body, p.copy())
        want = _line_gauss_seidel(p[:, 0], ~movable, rest, 1.1, passes)
        np.testing.assert_allclose(out[:, 0], want, atol=1e-12)
        np.testing.assert_array_equal(out[:, 1:], p[:, 1:])
        if passes == 1:   # the pull carried 5 edges down the line in one pass (Jacobi: 1)
            assert (np.abs(out[1:6, 0] - q[1:6, 0]) > 5e-4).all()
    assert not np.allclose(_line_gauss_seidel(p[:, 0], ~movable, rest, 1.1, 2),
                           _line_gauss_seidel(_line_gauss_seidel(p[:, 0], ~movable, rest, 1.1, 1),
                                              ~movable, rest, 1.1, 1))   # the second pass did go back


@pytest.mark.parametrize("compiled", [False, True] if HAVE_NUMBA else [False])
def test_the_weld_holds_inside_every_pass(compiled):
    """Known answer on a line of four vertices 1 cm over the plane, 0 fixed,
    1 and 2 a 1 mm weld group, 10 mm edges either side: vertex 0 pulled
    5 mm away stretches 0-1 to 15 mm. One pass (edge by edge): 0-1 moves 1
    by the excess over 11 mm (1.1 x 10 mm, a flat body), 4 mm toward 0,
    which opens 1-2 to 5 mm; 1-2 closes to its own limit (1.1 mm), both
    ends 1.95 mm; 2-3, now 11.95 mm, both ends 0.475 mm, which opens 1-2 to
    1.575 mm. The weld inside the pass closes it to 1 mm about its centre
    (without it the pass leaves 1.575 mm). Passes later every edge is
    within its limit and the weld closed."""
    body, faces = plane()
    q = np.array([[-0.0105, 0.01, 0.0], [-0.0005, 0.01, 0.0], [0.0005, 0.01, 0.0], [0.0105, 0.01, 0.0]])
    e = np.array([[0, 1], [1, 2], [2, 3]])
    movable = np.array([False, True, True, True])
    weld = ShortEdgeWeld(q, e)
    assert weld.n_groups == 1 and len(weld) == 2
    p = q.copy()
    p[0, 0] -= 0.005
    out = StrainLimit(q, e, faces, body, movable, iterations=1, compiled=compiled, weld=weld)(body, p.copy())
    centre = 0.5 * (-0.00255 - 0.000975)
    np.testing.assert_allclose(out[1:, 0], [centre - 0.0005, centre + 0.0005, 0.010025], atol=1e-12)
    alone = StrainLimit(q, e, faces, body, movable, iterations=1, compiled=compiled)(body, p.copy())
    np.testing.assert_allclose(alone[1:, 0], [-0.00255, -0.000975, 0.010025], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(alone[2] - alone[1]), 0.001575, atol=1e-12)
    lim = StrainLimit(q, e, faces, body, movable, iterations=50, compiled=compiled, weld=weld)
    many = lim(body, p.copy())
    assert np.linalg.norm(many[2] - many[1]) <= 0.001 + 1e-12
    assert (ratios(many, q, e) <= 1.1 + 1e-6).all()   # the flat skin's stretch 1 to rounding
    with pytest.raises(ValueError, match="reach vertex 2, the items have 2"):
        StrainLimit(q[:2], e[:1], faces, body, movable[:2], weld=weld)
    with pytest.raises(ValueError, match="each with a member"):
        weld_groups(np.array([1, 2]), np.array([0, 2]), np.ones(2))   # group 1 empty: a division by zero


@pytest.mark.parametrize("compiled", [False, True] if HAVE_NUMBA else [False])
def test_vertices_at_the_skin_take_the_jacobi_mean(compiled):
    """The line of four of the weld test (no weld), 1.2 mm over the plane:
    within NEAR_SKIN of the skin every vertex takes the mean of its edges'
    corrections computed at the pass's start. One pass: only 0-1 is over
    (15 mm), so 1 moves its 4 mm and 2 stays (edge by edge, 1-2 would have
    followed). At 1 cm over the plane the same line goes edge by edge."""
    body, faces = plane()
    e = np.array([[0, 1], [1, 2], [2, 3]])
    movable = np.array([False, True, True, True])
    x = np.array([-0.0105, -0.0005, 0.0005, 0.0105])
    for y, want in ((0.0012, [-0.0045, 0.0005, 0.0105]), (0.01, [-0.00255, -0.000975, 0.010025])):
        assert (y < NEAR_SKIN) == (y == 0.0012)
        q = np.stack([x, np.full(4, y), np.zeros(4)], axis=1)
        p = q.copy()
        p[0, 0] -= 0.005
        out = StrainLimit(q, e, faces, body, movable, iterations=1, compiled=compiled)(body, p.copy())
        np.testing.assert_allclose(out[1:, 0], want, atol=1e-12)


@pytest.mark.parametrize("compiled", [False, True] if HAVE_NUMBA else [False])
def test_a_vertex_far_behind_its_skin_is_not_cut_at_it(compiled):
    """An edge 10 mm long, 1 cm over the plane at rest. In the frame its fixed
    end is 13 cm under the plane and its free end 10 cm under (hair swung
    round: the skin it hung over at rest is not under it, and the
    penetration pass has put it outside the body): the free end moves
    straight to the allowed length, 1.1 x 10 mm from the fixed end (before,
    every move into that plane was cut and the edge stayed 3x long). Half of
    FOOT_LOST under the plane the move into the body is still cut: the end
    only slides along the plane."""
    from wearfit_usd.animate.strain_limit import FOOT_LOST
    body, faces = plane()
    e = np.array([[0, 1]])
    q = np.array([[0.0, 0.01, 0.0], [0.01, 0.01, 0.0]])
    movable = np.array([False, True])
    for y1, lost in ((-0.10, True), (-0.5 * FOOT_LOST, False)):
        assert (y1 < -FOOT_LOST) == lost
        p = np.array([[0.0, y1 - 0.03, 0.0], [0.01, y1, 0.0]])
        out = StrainLimit(q, e, faces, body, movable, iterations=1, compiled=compiled)(body, p.copy())
        np.testing.assert_array_equal(out[0], p[0])
        if lost:
            u = (p[1] - p[0]) / np.linalg.norm(p[1] - p[0])
            np.testing.assert_allclose(out[1], p[0] + 0.011 * u, atol=1e-12)
        else:
            assert out[1, 1] == pytest.approx(y1, abs=1e-12)      # nothing into the body
            assert out[1, 0] < p[1, 0] - 1e-3                       # it slid towards the fixed end
            assert np.linalg.norm(out[1] - out[0]) > 0.029          # and stays over its cap


def test_wavefront_levels_keep_the_order_of_edges_at_a_vertex():
    e = np.array([[0, 1], [2, 3], [1, 2], [3, 4], [0, 4]])
    fwd, bwd = wavefront_levels(e, 5)
    assert fwd.tolist() == [1, 1, 2, 2, 3]
    assert bwd.tolist() == [2, 3, 1, 2, 1]
    for lv in (fwd, bwd):
        for k in range(1, lv.max() + 1):   # one wave: no shared vertex
            ends = e[lv == k].ravel()
            assert len(np.unique(ends)) == len(ends)


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed: the numpy path is the only one")
def test_later_calls_on_the_same_body_reuse_its_caps_and_a_new_body_gets_its_own():
    """A frame's rounds after the weld call the limit again on the same
    body: the allowed lengths found by the first call are kept (the same
    numbers as computing them again), and a body that changed, even in
    place, gets fresh ones."""
    body, faces = plane()
    q, e = sheet(y=0.004)
    rng = np.random.default_rng(5)
    movable = np.ones(len(q), dtype=bool)
    bent = body * [1.25, 1.0, 0.9]
    bent[:, 1] += 0.3 * bent[:, 0] ** 2
    p = q + rng.normal(0.0, 0.004, q.shape)
    p[:, 1] += 0.3 * p[:, 0] ** 2
    kept = StrainLimit(q, e, faces, body, movable, limit=1.1, iterations=3)
    a = kept(bent, p.copy())
    caps = kept._caps.cap.copy()
    assert (caps > 0).sum() > 0
    b = kept(bent, a.copy(), iterations=3)           # the same body: the caps are reused
    assert kept._caps.cap[caps > 0] == pytest.approx(caps[caps > 0])
    fresh = StrainLimit(q, e, faces, body, movable, limit=1.1, iterations=3)
    fresh(bent, p.copy())
    fresh._caps = None                               # forget them: computed again
    np.testing.assert_allclose(b, fresh(bent, a.copy(), iterations=3), atol=1e-12)
    # the body changed in place (the same array): the caps of the new body
    bent *= [1.2, 1.0, 1.0]
    c = kept(bent, b.copy())
    other = StrainLimit(q, e, faces, body, movable, limit=1.1, iterations=3)
    np.testing.assert_allclose(c, other(bent, b.copy()), atol=1e-12)


def _mesh(name, pts, e):
    from wearfit_usd.model import Mesh
    tri = np.zeros((0, 3), dtype=np.int64)
    return Mesh(name, pts, tri, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))


def test_relax_first_dress_shortens_a_stretched_first_dress():
    from wearfit_usd.animate.try_on import relax_first_dress
    body, faces = plane()
    q, e = sheet()
    n = len(q)
    stretched = q * np.array([2.0, 1.0, 1.0])          # the first pose's dress: 2x along x
    items = [_mesh("loose", stretched.copy(), e), _mesh("rigid", stretched.copy(), e)]
    rest = [_mesh("loose", q, e), _mesh("rigid", q, e)]
    rigid = np.r_[np.zeros(n, dtype=bool), np.ones(n, dtype=bool)]
    edges = np.concatenate([e, e + n])
    assert ratios(stretched, q, e).max() > 1.9
    out = relax_first_dress(items, rest, rigid, edges, faces, body, body, passes=64)
    assert [m.name for m in out] == ["loose", "rigid"]
    assert ratios(out[0].points, q, e).max() < 1.1 + 0.01   # the limit (the body itself unstretched)
    np.testing.assert_array_equal(out[1].points, stretched)  # rigid parts are not moved
    np.testing.assert_array_equal(items[0].points, stretched)  # the input is left as it was
    # dresses that do not match point for point: nothing to relax
    assert relax_first_dress(items, rest[:1], rigid, edges, faces, body, body) is items


def test_edge_incidence_lists_each_vertex_s_edges_in_ascending_order():
    """The compiled pass gathers a vertex's corrections over its own edges in
    this order: ascending edge index, as one loop over all edges sums them."""
    from wearfit_usd.kernels import edge_incidence
    e = np.array([[2, 0], [0, 1], [1, 2], [3, 0]])
    ptr, idx = edge_incidence(e, 5)
    rows = [idx[ptr[v]:ptr[v + 1]].tolist() for v in range(5)]
    assert rows == [[0, 1, 3], [1, 2], [0, 2], [3], []]
