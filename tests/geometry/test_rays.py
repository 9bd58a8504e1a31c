"""The coverage rays' candidate search (geometry.rays): exact against brute force."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from wearfit_usd.geometry import rays
from wearfit_usd.geometry.rays import box_exit, cast_rays, centroid_reach, covering_points, march_rays, ray_triangle


def _brute(orig, dirs, pts, faces, t0, t1):
    r = np.repeat(np.arange(len(orig)), len(faces))
    t = np.tile(np.arange(len(faces)), len(orig))
    hit, tt = ray_triangle(orig[r], dirs[r], pts[faces[t, 0]], pts[faces[t, 1]], pts[faces[t, 2]], t0, t1)
    hit = hit.reshape(len(orig), len(faces))
    return hit, np.where(hit, np.abs(tt.reshape(len(orig), len(faces))), np.inf)


def test_covering_points_cover_every_point_of_every_triangle():
    rng = np.random.default_rng(0)
    # triangles from 1 mm to 30 cm, some slivers
    tri = rng.normal(size=(60, 3, 3)) * np.geomspace(0.001, 0.3, 60)[:, None, None]
    tri[:5, 2] = tri[:5, 0] + 1e-4 * (tri[:5, 1] - tri[:5, 0])
    radius = 0.01
    pts, owner = covering_points(tri, radius)
    assert owner.min() == 0 and owner.max() == len(tri) - 1
    assert len(pts) > 5 * len(tri)  # the big ones were subdivided
    w = rng.dirichlet(np.ones(3), size=400)
    for f in range(len(tri)):
        q = w @ tri[f]
        mine = pts[owner == f]
        d = np.linalg.norm(q[:, None] - mine[None], axis=2).min(axis=1)
        assert d.max() <= radius * (1 + 1e-9), f


@pytest.mark.parametrize("small_rays", [0, 10**9], ids=["kd-trees", "pairwise boxes"])
def test_cast_rays_long_segments_and_mixed_triangle_sizes(monkeypatch, small_rays):
    """Segments 100x longer than the median triangle (the hanging parts'
    50 cm rays against a 5 mm mesh) and a few triangles 60x the median;
    both search paths (KD-trees, or every pair's bounding boxes for few
    rays x triangles)."""
    monkeypatch.setattr(rays, "SMALL_RAYS", small_rays)
    rng = np.random.default_rng(7)
    pts, faces = _wavy_sheet_and_big_triangle()
    orig = rng.uniform(-0.15, 0.15, (500, 3))
    orig[:, 1] = rng.uniform(-0.4, 0.0, 500)
    dirs = rng.normal(size=(500, 3)) * [0.3, 1.0, 0.3]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    got = cast_rays(orig, dirs, pts, faces, -0.005, 0.5, chunk=61)
    hit, tt = _brute(orig, dirs, pts, faces, -0.005, 0.5)
    assert np.array_equal(got >= 0, hit.any(axis=1))
    assert 100 < hit.any(axis=1).sum() < 500 and hit[:, -1].sum() > 10
    rows = np.flatnonzero(got >= 0)
    assert np.allclose(tt[rows, got[rows]], tt[rows].min(axis=1))


def _wavy_sheet_and_big_triangle():
    """A 20 x 20 cm sheet of 1 cm triangles waving 3 cm, and one triangle
    60 cm across above it."""
    g = np.linspace(-0.1, 0.1, 21)
    x, z = np.meshgrid(g, g)
    pts = np.stack([x.ravel(), 0.03 * np.sin(20 * x.ravel()), z.ravel()], axis=1)
    faces = []
    for i in range(20):
        for j in range(20):
            a = i * 21 + j
            faces += [[a, a + 1, a + 22], [a, a + 22, a + 21]]
    big = np.array([[-0.3, 0.2, -0.3], [0.3, 0.25, -0.3], [0.0, 0.2, 0.3]])
    return np.concatenate([pts, big]), np.array(faces + [[441, 442, 443]])


@pytest.mark.parametrize("samples", [1, 8])
def test_march_rays_finds_the_first_hit_of_each_segment(samples):
    """Against brute force: the nearest hit (smallest t) of each segment
    from t_min to its own t_max, over 1 cm triangles and one 60x larger,
    marching one sample or eight a round."""
    pts, faces = _wavy_sheet_and_big_triangle()
    rng = np.random.default_rng(3)
    orig = rng.uniform(-0.15, 0.15, (400, 3))
    orig[:, 1] = rng.uniform(-0.4, 0.1, 400)
    dirs = rng.normal(size=(400, 3)) * [0.3, 1.0, 0.3]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_max = rng.uniform(0.05, 0.8, 400)
    tri = pts[faces]
    got, t = march_rays(orig, dirs, tri, cKDTree(centroid_reach(tri)[0]), 0.001, t_max, samples=samples)
    hit, _ = _brute(orig, dirs, pts, faces, 0.001, 0.8)
    _, tt = ray_triangle(np.repeat(orig, len(faces), axis=0), np.repeat(dirs, len(faces), axis=0),
                         np.tile(tri[:, 0], (400, 1)), np.tile(tri[:, 1], (400, 1)), np.tile(tri[:, 2], (400, 1)),
                         0.001, 0.8)
    tt = np.where(hit, tt.reshape(400, len(faces)), np.inf)
    tt[tt > t_max[:, None]] = np.inf
    want = np.isfinite(tt).any(axis=1)
    assert np.array_equal(got >= 0, want)
    assert 50 < want.sum() < 350 and (got == len(faces) - 1).sum() > 5
    rows = np.flatnonzero(want)
    assert np.allclose(t[rows], tt[rows].min(axis=1))
    assert np.allclose(tt[rows, got[rows]], t[rows])
    assert np.all(np.isinf(t[~want]))


def test_march_rays_refuses_endless_segments_and_ends_zero_directions():
    """A zero direction (a degenerate triangle's normal) meets nothing and
    the march ends at its finite end; an infinite end is refused."""
    pts, faces = _wavy_sheet_and_big_triangle()
    tri = pts[faces]
    tree = cKDTree(centroid_reach(tri)[0])
    orig = np.array([[0.0, -0.2, 0.0], [0.0, -0.2, 0.0]])
    dirs = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    hit, t = march_rays(orig, dirs, tri, tree, 0.001, 1.0)
    assert hit[0] >= 0 and np.isfinite(t[0]) and hit[1] == -1 and np.isinf(t[1])
    with pytest.raises(ValueError):
        march_rays(orig, dirs, tri, tree, 0.001, np.inf)


def test_box_exit_distance():
    o = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])
    d = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    t = box_exit(o, d, np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 2.0]))
    assert t == pytest.approx([1.0, 1.5, min(1.0 / 0.6, 2.0 / 0.8)])
