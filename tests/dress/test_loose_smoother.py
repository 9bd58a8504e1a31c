"""The loose-part smoothing takes its displacement in the frame of the body
under each loose patch: a part turned with the body keeps its shape, a body
of another shape that does not turn is smoothed as before."""
from dataclasses import replace

import numpy as np
import scipy.sparse as sp
from scipy.spatial import Delaunay
from scipy.spatial.transform import Rotation

from wearfit_usd.dress.apply import apply
from wearfit_usd.dress.binding import bind
from wearfit_usd.dress.corrections import LooseSmoother
from wearfit_usd.dress.plan import plan
from wearfit_usd.geometry.mesh import adjacency, edges
from wearfit_usd.io.bvh import read_bvh
from wearfit_usd.motion.retarget import retarget
from wearfit_usd.motion.skinning import skin_points, skinning_matrices


def _flap(seed=0):
    """An unevenly meshed flap (x, y in [0, 1], a little relief in z) whose
    top row is tight (weight 0) and the rest loose, bound to one body
    triangle above it. Returns points (M, 3), neighbours (M, M), weight
    (M,), the binding, body points (3, 3)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 1.0, size=(160, 2))
    xy = np.vstack([xy, np.c_[np.linspace(0, 1, 12), np.ones(12)]])  # the top row
    faces = Delaunay(xy).simplices
    pts = np.c_[xy, 0.05 * np.sin(7 * xy[:, 0]) * np.cos(5 * xy[:, 1])]
    nb = adjacency(faces, len(pts))
    weight = np.where(xy[:, 1] > 0.97, 0.0, 1.0)
    body = np.array([[0.0, 1.2, 0.0], [1.0, 1.2, 0.0], [0.5, 1.3, 0.2]])
    return pts, nb, weight, bind(body, np.array([[0, 1, 2]]), pts, k=1), body


def test_a_turned_part_keeps_its_shape():
    pts, nb, weight, bound, body = _flap()
    sm = LooseSmoother(nb, weight, bound=bound)
    assert len(sm.patches) == 1
    rot = Rotation.from_rotvec([0.4, 0.9, -0.3]).as_matrix()
    shift = np.array([0.3, -0.2, 0.1])
    turned, body_turned = pts @ rot + shift, body @ rot + shift
    got = sm(turned, pts, body_turned, body)
    np.testing.assert_allclose(got, turned, atol=1e-10)
    # without the body's frame, neighbour averaging of the rotation's
    # displacement bends the flap (what tore the ponytail's strands)
    plain = sm(turned, pts)
    assert np.abs(plain - turned).max() > 5e-3


def test_a_body_that_does_not_turn_is_smoothed_as_before():
    pts, nb, weight, bound, body = _flap(1)
    sm = LooseSmoother(nb, weight, bound=bound)
    bumpy = pts + 0.01 * np.random.default_rng(2).normal(size=pts.shape)
    moved_body = body + np.array([0.0, 0.0, 0.02])  # the body moves without turning
    a = sm(bumpy + [0.0, 0.0, 0.02], pts, moved_body, body)
    b = LooseSmoother(nb, weight)(bumpy + [0.0, 0.0, 0.02], pts)
    np.testing.assert_allclose(a, b, atol=1e-12)
    assert np.abs(a - bumpy - [0.0, 0.0, 0.02]).max() > 1e-3  # it did smooth


def _bound_to(body, faces, pts, triangles, weights):
    """A binding of ``pts`` to ``body`` with the given triangles and blend
    weights (M, k) (a real :class:`Binding`, its rows replaced)."""
    return replace(bind(body, faces, pts, k=1), triangles=np.asarray(triangles), weights=np.asarray(weights))


def test_body_patch_sums_the_binding_weights_per_corner():
    body = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
    faces = np.array([[0, 1, 2], [2, 1, 3]])
    b = _bound_to(body, faces, np.zeros((3, 3)) + 0.1, [[0, 1], [1, 1], [0, 0]], [[0.75, 0.25], [0.5, 0.5], [1.0, 0.0]])
    verts, w = b.body_patch(np.array([0, 1]))
    np.testing.assert_array_equal(verts, [0, 1, 2, 3])
    # triangle 0 carries 0.75 (to vertices 0, 1, 2), triangle 1 carries 1.25 (to 2, 1, 3)
    np.testing.assert_allclose(w, [0.75, 2.0, 2.0, 1.25])
    verts, w = b.body_patch(np.array([2]))  # a weight-0 triangle's own corners are left out
    np.testing.assert_array_equal(verts, [0, 1, 2])


def test_each_loose_patch_has_its_own_frame_and_boundary_values():
    # two chains of 10 loose vertices hanging from one shared tight vertex
    # (0), and a loose pair too small for a frame of its own hanging from 21
    e = np.array([(0, 1)] + [(i, i + 1) for i in range(1, 10)] + [(0, 11)] + [(i, i + 1) for i in range(11, 20)]
                 + [(21, 22), (22, 23)])
    m = 24
    nb = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(m, m)).tocsr()
    weight = np.ones(m)
    weight[[0, 21]] = 0.0
    pts = np.c_[np.r_[0.0, np.linspace(0.1, 1.0, 10), -np.linspace(0.1, 1.0, 10), 0.0, 0.0, 0.0],
                np.r_[0.0, np.zeros(20), 1.0, 0.9, 0.8], np.full(m, 0.5)]  # turned about the origin, 0.5 m off
    body = np.array([[0.0, 0.1, 0.5], [0.0, 0.1, 0.6], [0.1, 0.15, 0.5], [-0.1, 0.1, 0.55]])
    faces = np.array([[0, 1, 2], [1, 2, 3]])
    triangles = np.where(np.arange(m) < 11, 0, 1)[:, None]
    sm = LooseSmoother(nb, weight, bound=_bound_to(body, faces, pts, triangles, np.ones((m, 1))))
    groups = sorted(sorted(g.tolist()) for g, _, _ in sm.patches)
    assert groups == [list(range(0, 11)), [0] + list(range(11, 21))]
    # the shared tight vertex is a boundary value of each chain, in its frame
    assert sorted(sm.boundary.tolist()) == [0, 0, 21]
    assert sm.boundary_coupling.shape == (len(sm.free), 3)
    # the first chain turned with the body under it keeps its shape
    ra, rb = Rotation.from_rotvec([0, 0, 0.6]).as_matrix(), Rotation.from_rotvec([0, 0.9, -0.4]).as_matrix()
    out = pts.copy()
    out[0:11] = pts[0:11] @ ra
    out[11:21] = pts[11:21] @ rb
    body_now = body.copy()
    # the body triangle under each chain turns with it (vertex 1 and 2 are
    # shared: the frames are fitted, so close enough is what counts here)
    body_now[[0, 1, 2]] = body[[0, 1, 2]] @ ra
    body_now[3] = body[3] @ rb
    got = sm(out, pts, body_now, body)
    np.testing.assert_allclose(got[1:11], out[1:11], atol=1e-9)  # the first chain's frame is its exact turn


def _posed_through(character, bvh, frame):
    rt = retarget(read_bvh(bvh), character.skeleton, start=frame, end=frame + 1, fps=None)
    b = character.body
    return skin_points(b.points, b.joint_indices, b.joint_weights,
                       skinning_matrices(character.skeleton.bind_world, rt.world[0]))


def _edge_ratio(pl, pts, name):
    i = [m.name for m in pl.items].index(name)
    sl, item = pl.item_slices()[i], pl.items[i]
    e = edges(item.faces)
    return (np.linalg.norm(pts[sl][e[:, 0]] - pts[sl][e[:, 1]], axis=1)
            / np.linalg.norm(item.points[e[:, 0]] - item.points[e[:, 1]], axis=1))


def test_the_ponytail_keeps_its_strands_together_in_a_walks_first_frame(ref_female, bvh_dir):
    """Posed through the walk's first frame (head lifted, shoulders turned),
    the ponytail's strands, 0.3-1 mm apart, were pulled 3-4 mm apart by the
    smoothing of the neck's rotation (edge lengths p99 4.4x the asset's)."""
    pl = plan(ref_female)
    posed = _posed_through(ref_female, bvh_dir / "cmu_07_01_walk.bvh", 1)
    ratio = _edge_ratio(pl, apply(pl, posed, ref_female.body.faces, penetration=False)[0], "ponytail01")
    assert np.percentile(ratio, 99) < 2.5
    # strands a fraction of a millimetre apart weigh each other more in the
    # smoothing (geometry.mesh.short_edge_weights): 4.1x at most with uniform weights
    assert ratio.max() < 3.0


def test_a_suit_mid_stride_is_smoothed_in_its_patches_frames(ref_male, bvh_dir):
    """A tight vertex between two loose patches (a trouser leg and the
    jacket's tail) is a boundary value of each, in each one's frame: with
    one value for both, one patch's frame applied to the other's boundary
    value threw suit vertices off (here edges 5.6x instead of 2.7x; 118x and
    0.9 m on body_male_heavy walking)."""
    pl = plan(ref_male)
    assert np.bincount(pl.smoother.boundary).max() > 1  # a tight vertex borders two patches
    posed = _posed_through(ref_male, bvh_dir / "cmu_07_01_walk.bvh", 289)
    pts = apply(pl, posed, ref_male.body.faces, penetration=False)[0]
    assert np.abs(pts - pl.ref_points).max() < 0.5
    assert _edge_ratio(pl, pts, "male_casualsuit01").max() < 4.0


def _strip(gap=0.0008):
    """Two regular 11 x 6 grids (10 mm spacing) side by side in x, joined by
    a strip of triangles ``gap`` wide; every vertex loose but the outer
    columns. Returns points (M, 3), neighbours, weight, the strip's edges."""
    xs = np.arange(6) * 0.01
    ys = np.arange(11) * 0.01
    left = np.array([[x - xs[-1] - gap / 2, y, 0.0] for y in ys for x in xs])
    right = np.array([[x + gap / 2, y, 0.0] for y in ys for x in xs])
    pts = np.vstack([left, right])
    n = len(left)

    def quads(off):
        f = []
        for r in range(10):
            for c in range(5):
                a = off + r * 6 + c
                f += [[a, a + 1, a + 7], [a, a + 7, a + 6]]
        return f
    strip = []
    for r in range(10):
        a, b = r * 6 + 5, n + r * 6  # the left grid's last column, the right's first
        strip += [[a, b, b + 6], [a, b + 6, a + 6]]
    faces = np.array(quads(0) + quads(n) + strip)
    weight = np.ones(len(pts))
    weight[[r * 6 for r in range(11)]] = 0.0          # the left grid's outer column
    weight[[n + r * 6 + 5 for r in range(11)]] = 0.0  # the right grid's
    across = np.array([[r * 6 + 5, n + r * 6] for r in range(11)])
    return pts, adjacency(faces, len(pts)), weight, across


def test_a_narrow_strip_is_not_torn_by_the_smoothing():
    """The two sides of a 0.8 mm strip displaced apart by 10 mm (each side
    following its own body part): a uniform average pulls each side of the
    strip towards its own side and opens it; weighted by the edges' lengths
    the strip's two rows move together and the difference spreads over the
    grids' 10 mm edges."""
    pts, nb, weight, across = _strip()
    moved = pts.copy()
    n = len(pts) // 2
    moved[:n, 0] -= 0.005
    moved[n:, 0] += 0.005  # the strip's edges 0.8 -> 10.8 mm before smoothing
    gap = lambda p: np.linalg.norm(p[across[:, 0]] - p[across[:, 1]], axis=1)  # noqa: E731
    uniform = LooseSmoother(nb, weight)(moved, pts)
    weighted = LooseSmoother(nb, weight, points=pts)(moved, pts)
    assert gap(uniform).min() > 0.0025  # 0.8 -> 2.7-2.8 mm
    assert gap(weighted).max() < 0.0016
    # the grids' own edges take the difference instead (10 mm -> at most 12 mm)
    e = np.array(sp.triu(nb, k=1).nonzero()).T
    e = e[np.linalg.norm(pts[e[:, 0]] - pts[e[:, 1]], axis=1) > 0.005]
    ratio = np.linalg.norm(weighted[e[:, 0]] - weighted[e[:, 1]], axis=1) / np.linalg.norm(
        pts[e[:, 0]] - pts[e[:, 1]], axis=1)
    assert ratio.max() < 1.25
    # a regular grid alone is smoothed as with uniform weights
    half = slice(0, n)
    sub = nb.tocsr()[half][:, half]
    bumpy = pts[half] + 0.003 * np.random.default_rng(0).normal(size=(n, 3))
    np.testing.assert_allclose(LooseSmoother(sub, weight[half], points=pts[half])(bumpy, pts[half]),
                               LooseSmoother(sub, weight[half])(bumpy, pts[half]), atol=1e-12)


def test_the_hot_pants_seams_stay_closed_in_a_walks_first_frame(ref_female_longskirt, bvh_dir):
    """ref_female_longskirt's hot pants in the walk's first pose: their back
    seam spans the cleft of the buttocks (its two sides bound to the two
    walls, 2-3 mm apart) and their crotch has a strip of 0.7-1 mm edges.
    The back seam opened to 16-17 mm and the strip to 6-9 mm: edges 11.4x
    their length at most, 1.99x at p99. Smoothed over the bridge
    (:mod:`dress.bridges`) and weighted by length: 3.5x, 1.70x."""
    pl = plan(ref_female_longskirt)
    posed = _posed_through(ref_female_longskirt, bvh_dir / "cmu_07_01_walk.bvh", 1)
    pts = apply(pl, posed, ref_female_longskirt.body.faces, penetration=False)[0]
    ratio = _edge_ratio(pl, pts, "female_casualsuit02")
    assert ratio.max() < 5.0
    assert np.percentile(ratio, 99) < 1.8
