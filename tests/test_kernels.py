"""The compiled kernels (numba) give the numbers of the plain numpy/scipy
code they replace, on random and degenerate inputs."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

import wearfit_usd.kernels as kernels
from wearfit_usd.dress.binding import bind
from wearfit_usd.geometry.closest import closest_point_on_triangles
from wearfit_usd.demo.samples.body import make_body

pytestmark = pytest.mark.skipif(not kernels.HAVE_NUMBA, reason="numba not installed (the numpy paths run)")


def test_compiled_closest_matches_numpy_brute_force():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(60, 3))
    faces = rng.integers(0, 60, size=(80, 3))
    faces[:5, 2] = faces[:5, 1]                       # degenerate: two equal corners
    pts[faces[5, 2]] = 0.5 * (pts[faces[5, 0]] + pts[faces[5, 1]])  # collinear
    q = rng.normal(size=(500, 3))
    cand = rng.integers(0, 80, size=(500, 7))
    cand[:50] = np.arange(7)                           # the degenerate ones as candidates
    d2, s, t, inside, tri = kernels.closest_candidates(q, cand, pts, faces)
    cp, _, _ = closest_point_on_triangles(q[:, None, :], pts[faces[cand, 0]], pts[faces[cand, 1]],
                                          pts[faces[cand, 2]])
    ref = np.einsum("mci,mci->mc", q[:, None] - cp, q[:, None] - cp).min(axis=1)
    np.testing.assert_allclose(d2, ref, rtol=1e-9, atol=1e-12)
    a = pts[faces[tri, 0]]
    mine = a + s[:, None] * (pts[faces[tri, 1]] - a) + t[:, None] * (pts[faces[tri, 2]] - a)
    np.testing.assert_allclose(np.sum((q - mine) ** 2, axis=1), d2, rtol=1e-9, atol=1e-12)
    assert np.all(np.isin(tri, cand.ravel()))
    assert inside.any() and (~inside).any()


@pytest.mark.parametrize("radius,cell", [(0.01, None), (0.03, None), (0.2, None), (0.03, 0.03), (0.03, 0.007)])
def test_radius_grid_is_exact_nearest_within_radius(radius, cell):
    rng = np.random.default_rng(1)
    body = rng.uniform(-0.5, 0.5, size=(3000, 3)) * [1.0, 3.0, 0.5]
    q = rng.uniform(-0.8, 0.8, size=(4000, 3)) * [1.0, 3.0, 0.5]
    q[:10] += 100.0                                   # far outside the grid
    grid = kernels.RadiusGrid(body, radius, cell=cell)
    dref, iref = cKDTree(body).query(q, k=1, distance_upper_bound=radius)
    far = np.isinf(dref)
    assert far[:10].all() and far.sum() < len(q)
    # hints (any point, right or wrong, or none) bound the search only
    hints = [None, rng.integers(-1, len(body), size=len(q)), np.where(far, -1, iref)]
    for hint in hints:
        idx, d = grid.nearest(q, hint=hint)
        np.testing.assert_array_equal(idx < 0, far)
        np.testing.assert_allclose(d[~far], dref[~far], rtol=1e-12)
        np.testing.assert_array_equal(idx[~far], iref[~far])
        assert np.all(np.isinf(d[far]))


def test_compiled_binding_evaluation_matches_sparse_product():
    body = make_body(resolution=0.03).body
    rng = np.random.default_rng(2)
    items = body.points[rng.choice(len(body.points), 2000)] + rng.normal(scale=0.01, size=(2000, 3))
    b = bind(body.points, body.faces, items, k=5)
    moved = body.points * [1.1, 0.95, 1.05] + rng.normal(scale=0.002, size=body.points.shape)
    np.testing.assert_allclose(b.evaluate(moved), b.matrix @ b.stacked(moved), atol=1e-12)
    np.testing.assert_allclose(b.evaluate(body.points), items, atol=1e-9)


def test_compiled_face_normals():
    body = make_body(resolution=0.03).body
    n = kernels.face_normals(body.points, body.faces, unit=False)
    p = body.points[body.faces]
    np.testing.assert_allclose(n, np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), atol=1e-15)
    u = kernels.face_normals(body.points, body.faces, unit=True)
    np.testing.assert_allclose(u, n / np.linalg.norm(n, axis=1, keepdims=True), atol=1e-12)


_FALLBACK_SCRIPT = r"""
import sys, numpy as np
import wearfit_usd.kernels as kernels
assert not kernels.HAVE_NUMBA
from wearfit_usd.geometry.closest import SurfaceQuery
from wearfit_usd.dress.binding import bind
from wearfit_usd.animate.penetration_guard import PenetrationGuard
from wearfit_usd.demo.samples.body import make_body
body = make_body(resolution=0.03).body
rng = np.random.default_rng(3)
q = body.points[rng.choice(len(body.points), 500)] + rng.normal(scale=0.01, size=(500, 3))
sd = SurfaceQuery(body.faces, body.points).signed_distance(q)
b = bind(body.points, body.faces, q, k=5)
ev = b.evaluate(body.points * 1.05)
g = PenetrationGuard(body.faces, body.points, q)
out, n = g.apply(body.points * 0.98, q)
np.savez(sys.argv[1], sd=sd, ev=ev, out=out, n=n)
"""


def test_numpy_fallback_gives_the_same_numbers(tmp_path):
    """Without numba (WEARFIT_NO_NUMBA=1) the numpy/scipy paths run and agree."""
    import os
    import subprocess
    import sys
    from wearfit_usd.geometry.closest import SurfaceQuery
    from wearfit_usd.animate.penetration_guard import PenetrationGuard
    out = tmp_path / "fallback.npz"
    env = dict(os.environ, WEARFIT_NO_NUMBA="1")
    subprocess.run([sys.executable, "-c", _FALLBACK_SCRIPT, str(out)], check=True, env=env)
    ref = np.load(out)
    body = make_body(resolution=0.03).body
    rng = np.random.default_rng(3)
    q = body.points[rng.choice(len(body.points), 500)] + rng.normal(scale=0.01, size=(500, 3))
    np.testing.assert_allclose(SurfaceQuery(body.faces, body.points).signed_distance(q), ref["sd"], atol=1e-12)
    np.testing.assert_allclose(bind(body.points, body.faces, q, k=5).evaluate(body.points * 1.05), ref["ev"],
                               atol=1e-12)
    g = PenetrationGuard(body.faces, body.points, q)
    moved, n = g.apply(body.points * 0.98, q)
    assert n == int(ref["n"]) and n > 0
    np.testing.assert_allclose(moved, ref["out"], atol=1e-12)


def test_assign_rows_equals_fancy_assignment():
    rng = np.random.default_rng(6)
    a = rng.normal(size=(50, 3))
    idx = rng.choice(50, 20, replace=False)
    vals = rng.normal(size=(20, 3))
    ref = a.copy()
    ref[idx] = vals
    np.testing.assert_array_equal(kernels.assign_rows(a.copy(), idx, vals), ref)
    f = np.asfortranarray(a)  # not C-contiguous: the plain assignment path
    np.testing.assert_array_equal(kernels.assign_rows(f, idx, vals), ref)


def test_compiled_guard_matches_numpy_guard_over_frames():
    """The compiled guard frame (hinted nearest-vertex searches, one pass)
    gives the numpy path's pushes frame after frame, suspects included."""
    from wearfit_usd.animate.penetration_guard import PenetrationGuard
    body = make_body(resolution=0.03).body
    rng = np.random.default_rng(7)
    sel = rng.choice(len(body.points), 3000)
    from wearfit_usd.geometry.closest import vertex_normals
    n = vertex_normals(body.points, body.faces)
    items = body.points[sel] + n[sel] * rng.uniform(0.0005, 0.02, size=(3000, 1))
    guards = [PenetrationGuard(body.faces, body.points, items, compiled=c) for c in (True, False)]
    assert guards[0].compiled and not guards[1].compiled
    centre = body.points.mean(axis=0)
    total_inside = 0
    for f in range(8):
        # the body swells and shrinks around its centre, the items stay: vertices
        # sink in, are pushed, then their pushes decay
        s = 1.0 + 0.03 * np.sin(f)
        moved = centre + (body.points - centre) * s + rng.normal(scale=0.001, size=body.points.shape)
        (a, na), (b, nb) = (g.apply(moved, items) for g in guards)
        assert na == nb
        total_inside += na
        np.testing.assert_allclose(a, b, atol=1e-12)
        np.testing.assert_array_equal(guards[0].push > 0, guards[1].push > 0)
    assert total_inside > 100


def test_compiled_vertex_normals_match_sparse_incidence_sum():
    from wearfit_usd.geometry.closest import VertexNormals
    body = make_body(resolution=0.03).body
    vn = VertexNormals(body.faces, len(body.points))
    ref = vn.incidence @ kernels.face_normals(body.points, body.faces, unit=False)
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    np.testing.assert_allclose(vn(body.points), ref, atol=1e-14)
    faces = np.array([[0, 1, 2]], dtype=np.int64)  # vertex 3 unused: a zero normal
    out = kernels.vertex_normals(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]]), faces)
    np.testing.assert_allclose(out, [[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 0]])
