"""The compiled kernels (numba) give the numbers of their numpy twins, on
random and degenerate inputs; without numba (WEARFIT_NO_NUMBA=1) the public
kernels run the twins and give the same numbers."""
import os
import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import cKDTree

import wearfit_usd.kernels as kernels
from wearfit_usd.animate.penetration_guard import PenetrationGuard
from wearfit_usd.demo.samples.body import make_body
from wearfit_usd.dress.binding import bind
from wearfit_usd.dress.rigid_parts import RigidParts
from wearfit_usd.geometry.closest import SurfaceQuery, VertexNormals, closest_point_on_triangles, vertex_normals
from wearfit_usd.kernels import binding as kb
from wearfit_usd.kernels import closest as kc
from wearfit_usd.kernels import normals as kn

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


@pytest.mark.parametrize("radius", [0.01, 0.03, 0.2])
def test_radius_grid_per_call_radius_is_exact_and_leaves_the_grid_alone(radius):
    """A call's own radius (farther or nearer than the grid's cells) gives
    the exact nearest point within it, and the grid's radius is unchanged."""
    rng = np.random.default_rng(3)
    body = rng.uniform(-0.5, 0.5, size=(2000, 3))
    q = rng.uniform(-0.7, 0.7, size=(3000, 3))
    grid = kernels.RadiusGrid(body, 0.03)
    dref, iref = cKDTree(body).query(q, k=1, distance_upper_bound=radius)
    far = np.isinf(dref)
    assert far.any() and (~far).any()
    idx, d = grid.nearest(q, radius=radius)
    np.testing.assert_array_equal(idx < 0, far)
    np.testing.assert_array_equal(idx[~far], iref[~far])
    np.testing.assert_allclose(d[~far], dref[~far], rtol=1e-12)
    assert grid.radius == 0.03
    own = grid.nearest(q)[0]
    np.testing.assert_array_equal(own < 0, np.isinf(cKDTree(body).query(q, k=1, distance_upper_bound=0.03)[0]))
    with pytest.raises(ValueError, match="radius"):
        grid.nearest(q, radius=0.0)


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
    np.testing.assert_allclose(n, kn.face_normals_numpy(body.points, body.faces, unit=False), atol=1e-15)
    u = kernels.face_normals(body.points, body.faces, unit=True)
    np.testing.assert_allclose(u, n / np.linalg.norm(n, axis=1, keepdims=True), atol=1e-12)
    faces = np.array([[0, 1, 2], [0, 1, 1]], dtype=np.int64)  # a zero-area face: the zero vector
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(kernels.face_normals(pts, faces), kn.face_normals_numpy(pts, faces))


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
sq = SurfaceQuery(body.faces, body.points)
sd = sq.signed_distance(q)
b = bind(body.points, body.faces, q, k=5)
ev = b.evaluate(body.points * 1.05)
g = PenetrationGuard(body.faces, body.points, q)
out, n = g.apply(body.points * 0.98, q)
# the public kernels dispatch to their numpy twins
_, cand = sq.centroid_tree.query(q, k=6)
sig = kernels.closest_signed(q, cand, sq.points, sq.faces, sq.face_normal, sq.edge_normal, sq.edge_id, sq.ring)
cc = kernels.closest_candidates(q, cand, sq.points, sq.faces)
fn = kernels.face_normals(body.points, body.faces, unit=False)
vn = kernels.vertex_normals(body.points, body.faces)
be = kernels.binding_eval(body.points * 1.05, b.used_faces, b.compact, np.zeros_like(b._buf))
grid = kernels.RadiusGrid(body.points, 0.03)
gi, gd = grid.nearest(q)
np.savez(sys.argv[1], sd=sd, ev=ev, out=out, n=n, sig_d=sig[0], sig_n=sig[4], cc_d2=cc[0], fn=fn,
         vn=vn, be=be, gi=gi, gd=gd)
"""


def test_numpy_fallback_gives_the_same_numbers(tmp_path):
    """Without numba (WEARFIT_NO_NUMBA=1) the numpy/scipy paths run and agree."""
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
    sq = SurfaceQuery(body.faces, body.points)
    _, cand = sq.centroid_tree.query(q, k=6)
    sig = kernels.closest_signed(q, cand, sq.points, sq.faces, sq.face_normal, sq.edge_normal, sq.edge_id, sq.ring)
    np.testing.assert_allclose(sig[0], ref["sig_d"], atol=1e-12)
    np.testing.assert_allclose(sig[4], ref["sig_n"], atol=1e-12)
    cc = kernels.closest_candidates(q, cand, sq.points, sq.faces)
    np.testing.assert_allclose(cc[0], ref["cc_d2"], atol=1e-12)
    np.testing.assert_allclose(kernels.face_normals(body.points, body.faces, unit=False), ref["fn"], atol=1e-15)
    np.testing.assert_allclose(kernels.vertex_normals(body.points, body.faces), ref["vn"], atol=1e-14)
    b = bind(body.points, body.faces, q, k=5)
    np.testing.assert_allclose(kernels.binding_eval(body.points * 1.05, b.used_faces, b.compact,
                                                    np.zeros_like(b._buf)), ref["be"], atol=1e-12)
    gi, gd = kernels.RadiusGrid(body.points, 0.03).nearest(q)
    np.testing.assert_array_equal(gi, ref["gi"])
    np.testing.assert_allclose(gd, ref["gd"], rtol=1e-12)


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
    body = make_body(resolution=0.03).body
    rng = np.random.default_rng(7)
    sel = rng.choice(len(body.points), 3000)
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
    body = make_body(resolution=0.03).body
    vn = VertexNormals(body.faces, len(body.points))
    ref = vn.incidence @ kernels.face_normals(body.points, body.faces, unit=False)
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    np.testing.assert_allclose(vn(body.points), ref, atol=1e-14)
    faces = np.array([[0, 1, 2]], dtype=np.int64)  # vertex 3 unused: a zero normal
    out = kernels.vertex_normals(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]]), faces)
    np.testing.assert_allclose(out, [[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 0]])


def test_compiled_normal_sums_and_pseudo_normals_match_numpy():
    body = make_body(resolution=0.03).body
    fn = kernels.face_normals(body.points, body.faces)
    a, b = np.empty_like(body.points), np.empty_like(body.points)
    kn.face_normal_sums(body.faces, fn, a)
    kn.face_normal_sums_numpy(body.faces, fn, b)
    np.testing.assert_allclose(a, b, atol=1e-14)
    np.testing.assert_allclose(kernels.vertex_normals(body.points, body.faces),
                               kn.vertex_normals_numpy(body.points, body.faces), atol=1e-14)
    sq = SurfaceQuery(body.faces, body.points)
    verts = np.arange(0, len(body.points), 7)
    ref = kn.vertex_pseudo_normals_numpy(verts, body.points, sq.faces, sq.ring, fn)
    mine = np.array([kn.vertex_pseudo_normal(v, body.points, sq.faces, sq.ring, fn) for v in verts])
    np.testing.assert_allclose(mine, ref, atol=1e-12)
    np.testing.assert_allclose(ref, sq.vertex_normal[verts], atol=1e-12)


def test_compiled_closest_signed_matches_numpy_twin():
    """Signed closest points at faces, edges and corners (points placed on
    and beside vertices and edge midpoints), both sides of the surface."""
    body = make_body(resolution=0.03).body
    sq = SurfaceQuery(body.faces, body.points)
    rng = np.random.default_rng(4)
    p, f = body.points, body.faces
    vn = kernels.vertex_normals(p, f)
    on_vertex = p[::5] + vn[::5] * rng.uniform(-0.01, 0.01, size=(len(p[::5]), 1))
    mid = 0.5 * (p[f[::3, 0]] + p[f[::3, 1]])
    q = np.concatenate([on_vertex, mid + rng.normal(scale=0.004, size=mid.shape),
                        p[rng.choice(len(p), 400)] + rng.normal(scale=0.02, size=(400, 3))])
    _, cand = sq.centroid_tree.query(q, k=6)
    _, vi = sq.vertex_tree.query(q, k=1)
    cand = np.concatenate([cand, sq.ring[vi]], axis=1)
    args = (q, cand, sq.points, sq.faces, sq.face_normal, sq.edge_normal, sq.edge_id, sq.ring)
    mine, ref = kernels.closest_signed(*args), kc.closest_signed_numpy(*args)
    # distance, point and feature normal (the triangle and barycentrics may
    # differ where two candidates tie, to rounding, for the same point)
    for a, b in zip(mine[:2] + mine[4:], ref[:2] + ref[4:]):
        np.testing.assert_allclose(a, b, atol=1e-12)
    assert np.mean(mine[2] == ref[2]) > 0.9
    assert (mine[0] < 0).any() and (mine[0] > 0).any()
    d2, s, t, inside, tri = kernels.closest_candidates(q, cand, sq.points, sq.faces)
    corner = ~inside & ((s == 0) | (s == 1)) & ((t == 0) | (t == 1))
    assert corner.any() and (~inside & ~corner).any() and inside.any()
    np.testing.assert_allclose(d2, kc.closest_candidates_numpy(q, cand, sq.points, sq.faces)[0], atol=1e-12)


def test_compiled_binding_kernels_match_numpy_twins():
    body = make_body(resolution=0.03).body
    rng = np.random.default_rng(5)
    items = body.points[rng.choice(len(body.points), 1500)] + rng.normal(scale=0.01, size=(1500, 3))
    b = bind(body.points, body.faces, items, k=5)
    moved = body.points * [1.1, 0.95, 1.05]
    m = b.compact
    np.testing.assert_allclose(kernels.binding_eval(moved, b.used_faces, m, np.zeros_like(b._buf)),
                               kb.binding_eval_numpy(moved, b.used_faces, m, np.zeros_like(b._buf)), atol=1e-12)
    rows = np.sort(rng.choice(len(items), 900, replace=False)).astype(np.int64)
    sub = m[rows]
    sub.sort_indices()
    outs = [np.full((len(items), 3), 7.0) for _ in range(2)]
    for fn, out in zip((kernels.binding_eval_rows, kb.binding_eval_rows_numpy), outs):
        fn(moved, b.used_faces, sub.indptr, sub.indices, sub.data, rows, np.zeros_like(b._buf), out)
    np.testing.assert_allclose(outs[0], outs[1], atol=1e-12)
    assert np.all(np.delete(outs[0], rows, axis=0) == 7.0)
    # the smoothing's right side and the row update
    free = rng.choice(len(items), 300, replace=False).astype(np.int64)
    boundary = np.setdiff1d(np.arange(len(items)), free)[:200].astype(np.int64)
    lap = sp.random(300, 200, density=0.02, random_state=5, format="csr")
    ref_free, ref_boundary = items[free] * 0.9, items[boundary] * 1.1
    mass = rng.uniform(0.5, 2.0, size=300)
    rhs = [np.empty((300, 3)) for _ in range(2)]
    for fn, r in zip((kernels.diffusion_rhs, kb.diffusion_rhs_numpy), rhs):
        fn(items, free, boundary, ref_free, ref_boundary, mass, lap.indptr, lap.indices, lap.data, r)
    np.testing.assert_allclose(rhs[0], rhs[1], atol=1e-12)
    outs = [items.copy() for _ in range(2)]
    for fn, out in zip((kernels.add_rows, kb.add_rows_numpy), outs):
        fn(out, free, ref_free, rhs[0])
    np.testing.assert_array_equal(outs[0], outs[1])


def test_compiled_similarities_match_numpy_twins():
    rng = np.random.default_rng(8)
    body = rng.normal(size=(300, 3))
    items = rng.normal(size=(200, 3))
    groups = [(gv, rng.choice(300, 40, replace=False), rng.uniform(0.1, 1.0, size=40))
              for gv in np.array_split(rng.permutation(200)[:150], 3)]
    moved = body * 1.2 @ np.linalg.qr(rng.normal(size=(3, 3)))[0] + rng.normal(scale=0.01, size=body.shape)
    for scale in (True, False):
        parts = RigidParts(groups, body, items, scale=scale)
        args = (moved, parts._mean, parts._cov, parts._src_mean, parts._src_var, scale)
        mine, ref = kernels.similarity_transforms(*args), kb.similarity_transforms_numpy(*args)
        for a, b in zip(mine, ref):
            np.testing.assert_allclose(a, b, atol=1e-12)
        outs = [items.copy() for _ in range(2)]
        for fn, out in zip((kernels.similarity_place, kb.similarity_place_numpy), outs):
            fn(parts._ref_all, parts._rows, parts._group, *mine, out)
        np.testing.assert_allclose(outs[0], outs[1], atol=1e-12)


def test_compiled_layer_ray_search_matches_numpy_twin():
    # rays down onto a crumpled sheet from random points, each among a random
    # handful of its triangles (padded), some from behind, some missing
    from wearfit_usd.kernels import layers as kl
    rng = np.random.default_rng(5)
    n = 12
    u = np.linspace(0.0, 0.11, n)
    x, y = np.meshgrid(u, u, indexing="ij")
    pts = np.column_stack([x.ravel(), y.ravel(), rng.normal(0.0, 0.004, n * n)])
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    faces = np.concatenate([np.column_stack([a, a + n, a + n + 1]), np.column_stack([a, a + 1, a + n + 1])])
    r = 400
    top = np.column_stack([rng.uniform(0, 0.11, r), rng.uniform(0, 0.11, r), rng.uniform(-0.01, 0.03, r)])
    dirs = np.column_stack([rng.normal(0, 0.2, r), rng.normal(0, 0.2, r), -np.ones(r)])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs[::7] *= -1.0
    # each ray's 30 nearest triangles (by centroid), a third of them left out
    cand = cKDTree(pts[faces].mean(axis=1)[:, :2]).query(top[:, :2], k=30)[1].astype(np.int64)
    cand[rng.random((r, 30)) < 0.3] = -1
    reach = rng.uniform(0.005, 0.04, r)
    compiled, c_face = kernels.first_hits(pts, faces, cand, top, dirs, reach)
    twin, t_face = kl.first_hits_numpy(pts, faces, cand, top, dirs, reach)
    np.testing.assert_allclose(compiled, twin, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(c_face, t_face)
    np.testing.assert_array_equal(c_face < 0, ~np.isfinite(twin))
    assert 50 < np.isfinite(twin).sum() < r - 50      # hits and misses both tested
