"""XPBD cloth of the loose item parts (animate.cloth, kernels.cloth, animate.loose)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tests.conftest import BVH_DIR, USD_DIR
from wearfit_usd.animate.cloth import (
    LAYER_GAP,
    ClothSolver,
    PushCarry,
    colour_edges,
    default_collider,
    inner_layer_field,
    inner_layer_margin,
    tethers,
)
from wearfit_usd.dress import regions as R
from wearfit_usd.geometry.closest import SurfaceQuery
from wearfit_usd.geometry.mesh import adjacency
from wearfit_usd.geometry.mesh import edges as mesh_edges
from wearfit_usd.kernels import HAVE_NUMBA


def grid_sheet(n: int = 11, size: float = 1.0, y: float = 0.0):
    """n x n vertices over [0, size]^2 in the xz plane at height y; row i is x = i * size / (n - 1)."""
    u = np.linspace(0.0, size, n)
    gx, gz = np.meshgrid(u, u, indexing="ij")
    pts = np.stack([gx.ravel(), np.full(gx.size, y), gz.ravel()], axis=1)
    a = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([a, a + n, a + 1], 1), np.stack([a + 1, a + n, a + n + 1], 1)])
    return pts, faces.astype(np.int64)


def uv_sphere(rings: int = 16, r: float = 1.0, centre=(0.0, 0.0, 0.0)):
    """A closed triangulated sphere with outward faces."""
    m = 2 * rings
    th = np.linspace(0.0, np.pi, rings)[1:-1]
    ph = np.linspace(0.0, 2 * np.pi, m, endpoint=False)
    body = np.stack([np.outer(np.sin(th), np.cos(ph)).ravel(), np.repeat(np.cos(th), m),
                     np.outer(np.sin(th), np.sin(ph)).ravel()], axis=1)
    pts = np.concatenate([[[0.0, 1.0, 0.0]], body, [[0.0, -1.0, 0.0]]]) * r + np.asarray(centre)
    j = np.arange(m)
    faces = [np.stack([np.zeros(m, int), 1 + (j + 1) % m, 1 + j], 1)]
    for i in range(len(th) - 1):
        a, b = 1 + i * m + j, 1 + i * m + (j + 1) % m
        faces += [np.stack([a, b, b + m], 1), np.stack([a, b + m, a + m], 1)]
    last, base = len(pts) - 1, 1 + (len(th) - 1) * m
    faces.append(np.stack([np.full(m, last), base + j, base + (j + 1) % m], 1))
    return pts, np.concatenate(faces).astype(np.int64)


def sheet_plan(faces):
    return SimpleNamespace(mesh=SimpleNamespace(edges=mesh_edges(faces)))


FAR_BODY = uv_sphere(6, 0.05, (50.0, 50.0, 50.0))  # a collider far out of reach


def edge_ratio(points, ref, e):
    return np.linalg.norm(points[e[:, 0]] - points[e[:, 1]], axis=1) / np.linalg.norm(ref[e[:, 0]] - ref[e[:, 1]],
                                                                                      axis=1)


def test_colour_edges_are_independent_sets():
    _, faces = grid_sheet(9)
    e = mesh_edges(faces)
    order, ptr = colour_edges(e, 81)
    assert sorted(order.tolist()) == list(range(len(e)))
    for c in range(len(ptr) - 1):
        v = e[order[ptr[c]:ptr[c + 1]]].ravel()
        assert len(np.unique(v)) == len(v)
    assert len(ptr) - 1 <= 12  # about the largest vertex degree (6 on this grid)


def test_tethers_of_a_chain_and_a_fork():
    # free particles 0-3 (3 joined to nothing), kinematic 4 and 5:
    # 5 -0.5- 0 -0.1- 1 -0.2- 2 -0.3- 4
    edges = np.array([[2, 4], [1, 2], [0, 1], [0, 5]], dtype=np.int64)
    rest = np.array([0.3, 0.2, 0.1, 0.5])
    t = tethers(edges, rest, 4, 6, 0.02)
    assert t.anchor.tolist() == [5, 4, 4, -1]
    np.testing.assert_allclose(t.length[:3], np.array([0.5, 0.5, 0.3]) * 1.02)
    assert np.isinf(t.length[3])
    assert (tethers(edges, rest, 4, 6, None).anchor == -1).all()


def test_tethers_keep_a_soft_sheet_from_sagging():
    # edges as soft as rubber: without tethers the hanging sheet sags far past
    # its length; with them no vertex is farther from the pinned edge than
    # its rest distance along the sheet (plus the slack)
    pts, faces = grid_sheet(9, 0.8)
    pts = pts[:, [1, 0, 2]] * np.array([1.0, -1.0, 1.0])
    w = np.ones(len(pts))
    w[:9] = 0.0
    bp, bf = FAR_BODY
    low = {}
    for slack in (None, 0.02):
        cs = ClothSolver(sheet_plan(faces), bf, bp, pts, weights=w, attach_alpha=1e9, stretch_alpha=1e-3,
                         tether_slack=slack)
        for _ in range(60):
            out = cs.step(bp, pts, 1.0 / 30.0)
        low[slack] = out[:, 1].min()
    assert low[None] < -0.8 * 1.15
    assert low[0.02] > -0.8 * 1.02 - 1e-6


def test_set_rest_changes_only_the_hanging_part():
    pts, faces = grid_sheet(9, 0.8)
    w = np.clip(pts[:, 0] / 0.4, 0.0, 1.0)            # 0 at x = 0 rising to 1 from x = 0.4
    bp, bf = FAR_BODY
    cs = ClothSolver(sheet_plan(faces), bf, bp, pts, weights=w)
    before = cs.rest.copy()
    cs.set_rest(pts * 1.1)
    pe = cs.particles[cs.edges]
    hang = (w[pe] >= 0.5).all(axis=1)
    assert hang.any() and (~hang).any()
    np.testing.assert_allclose(cs.rest[hang], 1.1 * before[hang])
    np.testing.assert_array_equal(cs.rest[~hang], before[~hang])
    assert np.isfinite(cs.tethers.length[w[cs.free] >= 0.5]).all()


def test_hanging_sheet_settles_to_its_length():
    # a 1 m sheet, pinned along x = 0, starts horizontal and falls: it must hang
    # straight down, 1 m long, edges within a few per cent of their length
    pts, faces = grid_sheet(11, 1.0)
    w = np.ones(len(pts))
    w[:11] = 0.0
    bp, bf = FAR_BODY
    cs = ClothSolver(sheet_plan(faces), bf, bp, pts, weights=w, attach_alpha=1e9)
    for _ in range(240):  # 8 s at 30 fps
        out = cs.step(bp, pts, 1.0 / 30.0)
    e = mesh_edges(faces)
    r = edge_ratio(out, pts, e)
    assert r.max() < 1.05 and r.min() > 0.95
    assert out[:, 1].min() == pytest.approx(-1.0, abs=0.05)
    assert np.ptp(out[:, 0]) < 0.05                      # hangs straight down from x = 0
    assert np.abs(cs.v).max() < 0.05                     # at rest


def test_falling_sheet_does_not_go_through_a_sphere():
    pts, faces = grid_sheet(15, 1.2, y=0.45)
    pts[:, [0, 2]] -= 0.6
    sp, sf = uv_sphere(16, 0.4)
    cs = ClothSolver(sheet_plan(faces), sf, sp, pts, weights=np.ones(len(pts)), attach_alpha=1e9, friction=0.5)
    q = SurfaceQuery(sf, sp)
    for f in range(30):  # 1 s: it falls 5 cm onto the sphere and drapes
        out = cs.step(sp, pts, 1.0 / 30.0)
        assert q.signed_distance(out).min() > -0.002, f
    assert out[:, 1].min() < 0.2  # it did drape round the sphere
    assert edge_ratio(out, pts, mesh_edges(faces)).max() < 1.1


def test_floors_are_the_tangent_planes_under_the_free_vertices():
    # a sheet settled on a sphere: each free vertex's floor is the tangent
    # plane of the sphere vertex nearest to it (its point and unit normal),
    # the vertex on its outer side; rows left out and bound vertices get none
    pts, faces = grid_sheet(15, 1.2, y=0.45)
    pts[:, [0, 2]] -= 0.6
    w = np.ones(len(pts))
    w[:15] = 0.0                                     # one edge row bound
    sp, sf = uv_sphere(16, 0.4)
    cs = ClothSolver(sheet_plan(faces), sf, sp, pts, weights=w, attach_alpha=1e9, friction=0.5)
    for _ in range(30):
        out = cs.step(sp, pts, 1.0 / 30.0)
    rows = np.zeros(len(pts), dtype=bool)
    rows[: len(pts) // 2] = True
    fl = cs.floors(rows=rows)
    has = np.any(fl[:, 3:] != 0.0, axis=1)
    assert not has[:15].any() and not has[len(pts) // 2:].any()
    assert has.sum() > 20
    np.testing.assert_allclose(np.linalg.norm(fl[has, 3:], axis=1), 1.0, atol=1e-9)
    # on the sphere (within 6 cm of a vertex; they are 8 cm apart): the floor's vertex is the nearest one, or nearly
    dn, _ = cKDTree(sp).query(out)
    on = np.flatnonzero(has & (dn < 0.06))
    assert len(on) > 10
    np.testing.assert_array_less(np.linalg.norm(out[on] - fl[on, :3], axis=1), 1.5 * dn[on] + 1e-9)
    # each floor point is a sphere vertex, its normal the sphere's outward radius there
    d, i = cKDTree(sp).query(fl[has, :3])
    np.testing.assert_allclose(d, 0.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", fl[has, 3:], sp[i] / 0.4), 1.0, atol=0.02)
    assert np.einsum("ij,ij->i", out[has] - fl[has, :3], fl[has, 3:]).min() > -0.002
    np.testing.assert_array_equal(cs.floors()[has], fl[has])


def test_moving_sphere_pushes_the_cloth_not_through():
    # a sphere sweeping through a hanging sheet at 2 m/s pushes it along
    pts, faces = grid_sheet(13, 0.6)
    pts = pts[:, [1, 0, 2]] * np.array([1.0, -1.0, 1.0])   # the sheet in the yz plane, hanging from y = 0
    w = np.ones(len(pts))
    w[:13] = 0.0
    sp0, sf = uv_sphere(16, 0.12, (-0.3, -0.35, 0.3))
    cs = ClothSolver(sheet_plan(faces), sf, sp0, pts, weights=w, attach_alpha=1e9)
    q = SurfaceQuery(sf, sp0)
    for f in range(1, 11):  # 0.33 s, 0.67 m
        body = sp0 + np.array([2.0 * f / 30.0, 0.0, 0.0])
        out = cs.step(body, pts, 1.0 / 30.0)
        q.update(body)
        assert q.signed_distance(out).min() > -0.003, f
    assert out[:, 0].max() > 0.2  # carried along in front of the sphere


def test_inertia_swings_then_settles():
    # the pinned edge moves 30 cm sideways in 0.3 s and stops: the free end
    # lags, keeps moving after the stop, then comes to rest under the edge
    pts, faces = grid_sheet(9, 0.8)
    pts = pts[:, [1, 0, 2]] * np.array([1.0, -1.0, 1.0])
    w = np.ones(len(pts))
    w[:9] = 0.0
    bp, bf = FAR_BODY
    cs = ClothSolver(sheet_plan(faces), bf, bp, pts, weights=w, attach_alpha=1e9, damping=1.0)
    free_end = np.arange(len(pts) - 9, len(pts))
    shift = np.zeros(3)
    for f in range(1, 10):  # across the sheet's plane: it swings like a pendulum
        shift = np.array([f / 9 * 0.3, 0.0, 0.0])
        out = cs.step(bp, pts + shift, 1.0 / 30.0)
    at_stop = out[free_end, 0].mean()
    assert at_stop < 0.3 - 0.02                                     # lagging behind
    out = cs.step(bp, pts + shift, 1.0 / 30.0)
    out = cs.step(bp, pts + shift, 1.0 / 30.0)
    assert out[free_end, 0].mean() > at_stop + 0.005                # still moving on after the stop
    swing = [cs.step(bp, pts + shift, 1.0 / 30.0)[free_end, 0].mean() for _ in range(60)]
    assert max(swing) > 0.3 + 0.01                                  # overshoots: a swing, not a drag
    for _ in range(300):
        out = cs.step(bp, pts + shift, 1.0 / 30.0)
    assert np.abs(cs.v).max() < 0.02
    np.testing.assert_allclose(out[free_end, 0], 0.3, atol=0.02)    # settled under the moved edge


def test_shot_starts_moving_with_the_body_after_preroll():
    # a sheet hanging from its pinned edge while the body (and the edge) walks
    # sideways at 1.2 m/s from the shot's first frame: after the preroll the
    # cloth starts with its attachment line's velocity and hangs straight
    # under the edge (known answer: a rigid translation); started at rest
    # (reset, no preroll) it is left behind and swings back
    pts, faces = grid_sheet(9, 0.8)
    pts = pts[:, [1, 0, 2]] * np.array([1.0, -1.0, 1.0])   # in the yz plane, hanging from y = 0
    w = np.ones(len(pts))
    w[:9] = 0.0
    bp, bf = FAR_BODY
    free_end = np.arange(len(pts) - 9, len(pts))
    speed, dt = np.array([1.2, 0.0, 0.0]), 1.0 / 30.0
    lag = {}
    for start in ("preroll", "rest"):
        cs = ClothSolver(sheet_plan(faces), bf, bp, pts, weights=w, attach_alpha=1e9)
        if start == "preroll":
            settled = cs.preroll(bp, bp, lambda body: pts, dt)
            np.testing.assert_allclose(settled, pts, atol=0.005)  # it already hung (stretched 2 mm)
        else:
            cs.reset(bp, pts)
        worst = 0.0
        for f in range(1, 16):
            out = cs.step(bp + f * dt * speed, pts + f * dt * speed, dt)
            worst = max(worst, float(np.abs(out[free_end, 0] - f * dt * speed[0]).max()))
        lag[start] = worst
    assert lag["preroll"] < 1e-9                   # moves rigidly with its edge
    assert lag["rest"] > 0.1


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed")
@pytest.mark.parametrize("iterations", [1, 3])
def test_numba_kernel_matches_numpy_twin(iterations):
    pts, faces = grid_sheet(12, 1.0, y=0.43)
    pts[:, [0, 2]] -= 0.5
    w = np.linspace(0.0, 1.0, len(pts)) ** 0.5
    w[:12] = 0.0
    sp, sf = uv_sphere(14, 0.4)
    runs = []
    for compiled in (True, False):
        cs = ClothSolver(sheet_plan(faces), sf, sp, pts, weights=w, compiled=compiled, attach_alpha=0.05,
                         iterations=iterations)
        outs = []
        for f in range(1, 8):
            body = sp + np.array([0.0, 0.01 * f, 0.02 * f])
            outs.append(cs.step(body, pts + np.array([0.0, 0.0, 0.01 * f]), 1.0 / 30.0))
        runs.append((np.array(outs), cs.hint.copy(), cs.v.copy()))
    assert cs.n_free > 100 and (runs[0][1] >= 0).all() and (cs.tethers.anchor >= 0).all()
    np.testing.assert_allclose(runs[0][0], runs[1][0], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    np.testing.assert_allclose(runs[0][2], runs[1][2], rtol=0, atol=1e-6)


def test_loose_weights_of_the_long_skirt():
    from wearfit_usd.animate.loose import cloth_weights
    from wearfit_usd.dress.plan import plan
    from wearfit_usd.io.usd import read_character
    ref = read_character(USD_DIR / "ref_female_longskirt.usda")
    p = plan(ref)
    w = cloth_weights(p)
    sl = dict(zip([m.name for m in p.items], p.item_slices()))
    skirt = w[sl["long_skirt"]]
    y = p.ref_points[sl["long_skirt"], 1]
    assert (skirt[y > y.max() - 0.03] == 0).all()             # the waistband follows the binding
    assert (skirt[y < y.min() + 0.3] == 1).all()              # the lower skirt hangs free
    assert (w[sl["shoes02"]] == 0).all()                      # rigid parts never


def _outside_skirt(skirt_faces, skirt_pts, body_pts, sign):
    """Signed distance of body vertices to the skirt surface, > 0 outside it."""
    return SurfaceQuery(skirt_faces, skirt_pts).closest(body_pts)["distance"] * sign


def _shot_frames(path, item, frames):
    """(body points, item points) in internal space of the shot at path, per frame."""
    from pxr import Usd, UsdGeom, UsdSkel

    from wearfit_usd.io.usd import read_character
    from wearfit_usd.motion.skinning import skin_mesh
    from wearfit_usd.transforms import transform_points
    stage = Usd.Stage.Open(str(path))
    shot = read_character(path)
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath("/Root/Character")), Usd.PrimDefaultPredicate)
    sq = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath("/Root/Character/Skeleton")))
    prim = UsdGeom.Mesh(stage.GetPrimAtPath(f"/Root/Items/{item}"))
    faces = [m.faces for m in shot.items if m.name == item][0]
    for f in frames:
        local = np.array(sq.ComputeJointLocalTransforms(f))
        body = skin_mesh(shot.body, shot.skeleton, shot.skeleton.world_from_local(local))
        pts = transform_points(np.array(prim.GetPointsAttr().Get(f), dtype=np.float64), shot.to_internal)
        yield faces, body, pts


def test_longskirt_walk_keeps_the_legs_inside(tmp_path):
    # ref_female_longskirt on body_female_heavy, first 25 frames of the CMU
    # walk at 30 fps. Before: the skirt bound to the hips, the legs came out
    # through it from frame 0 on (61 % of the leg skin inside it in the worst
    # frame outside) and its edges stretched up to 22x (p99 6.8x) against the
    # static dress
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    ref = read_character(USD_DIR / "ref_female_longskirt.usda")
    tgt = read_character(USD_DIR / "body_female_heavy.usdc")
    walk = read_bvh(BVH_DIR / "cmu_07_01_walk.bvh")
    static = tmp_path / "static.usdc"   # frame 0 without cloth: the static dress
    animate(ref, tgt, walk, static, AnimateOptions(start=1, end=2, fps=30, cloth=False))
    faces, _, dress = next(_shot_frames(static, "long_skirt", [0]))
    e = mesh_edges(faces)
    # watched: the body vertices inside the skirt as authored (the reference at
    # rest, same body topology), within 15 cm of it, between 10 cm under its
    # waistband and 5 cm above its hem
    ref_skirt = [m for m in ref.items if m.name == "long_skirt"][0]
    r = SurfaceQuery(faces, ref_skirt.points).closest(ref.body.points)["distance"]
    y, sy = ref.body.points[:, 1], ref_skirt.points[:, 1]
    near = (np.abs(r) < 0.15) & (y > sy.min() + 0.05) & (y < sy.max() - 0.10)
    sign = -1.0 if np.median(r[near]) > 0 else 1.0
    watch = np.flatnonzero(near & (r * sign < -0.002))
    assert len(watch) > 500 and np.mean(r[near] * sign < 0) > 0.95
    out = tmp_path / "walk.usdc"
    rep = animate(ref, tgt, walk, out, AnimateOptions(start=1, end=101, fps=30, measure_every=4))
    assert rep.frames == 25 and rep.cloth_vertices > 500
    worst_out, ratios = 0.0, []
    for _, body, pts in _shot_frames(out, "long_skirt", range(0, rep.frames, 2)):
        d = SurfaceQuery(faces, pts).closest(body[watch])["distance"] * sign
        worst_out = max(worst_out, float(np.mean(d > 0.005)))
        ratios.append(edge_ratio(pts, dress, e))
    ratios = np.array(ratios)
    # now (measured): 2 % worst frame, stretch p99 2.1x, max 6.6x (a 6 mm edge)
    assert worst_out < 0.05, worst_out
    assert np.percentile(ratios, 99, axis=1).max() < 2.5
    assert ratios.max() < 8.0
    assert rep.worst_frame_penetration < 0.01
    # a straight skirt to the ankles: its hem (1.19 m) cannot go round the
    # legs in a full stride (the walk's first frame: 1.74 m), and says so
    hem = rep.narrow_hems["long_skirt"]
    assert 1.1 < hem["hem_m"] < 1.3 and hem["outline_max_m"] > 1.1 * hem["hem_m"]
    assert 0 < hem["frames"] < rep.frames and list(rep.narrow_hems) == ["long_skirt"]


def test_longskirt_walk_first_frame_keeps_the_calf_inside(tmp_path):
    # ref_female_longskirt on body_female_heavy, CMU walk, frames 0-1 at 30
    # fps: the strain limit after the cloth shortened skirt edges over the
    # back calf and took free vertices up to 8 mm into it (new penetrations
    # 1.68 %, the skin showing through; its floor was the static skin under
    # them, elsewhere). With the cloth's skin under them as a floor: 0 %.
    # The stretch max of these two frames, 1.42 / 1.46 until session 31, is
    # 1.33 / 1.53 since the first pose's dress takes the shoes where the
    # shot skins them (session 32): the cloth's first step over the issue's
    # 1.5 on one 16 mm edge behind the calf, 16 cm over the floor (the whole walk,
    # measured every second frame: 1.43 -> 1.47); 1.32 / 1.52 with the strain
    # limit's Gauss-Seidel passes (session 33; 1.34 / 1.62 before the vertices
    # at the skin kept the Jacobi mean)
    from wearfit_usd.animate.try_on import AnimateOptions, animate
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    ref = read_character(USD_DIR / "ref_female_longskirt.usda")
    tgt = read_character(USD_DIR / "body_female_heavy.usdc")
    rep = animate(ref, tgt, read_bvh(BVH_DIR / "cmu_07_01_walk.bvh"), tmp_path / "walk.usdc",
                  AnimateOptions(start=1, end=9, fps=30, measure_every=1))
    assert rep.frames == 2
    assert max(rep.motion_series["long_skirt"]["new_pen_pct"]) < 0.5
    assert max(rep.motion_series["long_skirt"]["stretch_max"]) < 1.6


def test_default_collider_leaves_out_the_arms_of_the_plans_body():
    """The cloth collides with every body vertex but the arms' (a hand beside
    a skirt threw its side out in a flap: the arms were kept because the
    lookup read a plan field that no longer exists)."""
    labels = np.array([R.TORSO, R.LEFT_ARM, R.RIGHT_ARM, R.LEFT_LEG, R.HEAD, R.RIGHT_LEG])
    plan = SimpleNamespace(regions=SimpleNamespace(body=labels))
    assert default_collider(plan, 6).tolist() == [True, False, False, True, True, True]
    # regions of another body (other vertex count): every vertex collides
    assert default_collider(plan, 7).all()


def test_inner_layer_margin_known_answers():
    """Over a flat skin (y = 0, normals +y): cloth samples of item 1 at 3 cm;
    a bound layer of item 0 at 2 cm under the first sample, at 4 cm (over the
    cloth, not under it) under the second, none near the third; a bound
    vertex of the cloth's own item under the fourth. Only the first keeps
    2 cm + LAYER_GAP; a layer higher than the sample's own clearance would
    be capped at it."""
    xs = np.array([0.0, 0.2, 0.4, 0.6])
    body = np.stack([np.repeat(np.linspace(-0.1, 0.7, 9), 9), np.zeros(81),
                     np.tile(np.linspace(-0.1, 0.1, 9), 9)], axis=1)
    normals = np.tile([0.0, 1.0, 0.0], (len(body), 1))
    cloth = np.stack([xs, np.full(4, 0.03), np.zeros(4)], axis=1)
    layer = np.array([[0.0, 0.02, 0.005], [0.2, 0.04, 0.005], [0.6, 0.01, 0.005]])
    items = np.concatenate([layer[:2], cloth, layer[2:]])  # item 0: rows 0-1; item 1: rows 2-6
    plan = SimpleNamespace(offsets=np.array([0, 2, 7]))
    w = np.array([0, 0, 1, 1, 1, 1, 0], dtype=float)
    particles = np.array([2, 3, 4, 5])
    samples = np.stack([np.arange(4), np.arange(4)], axis=1)
    got = inner_layer_margin(plan, w, items, particles, samples, cloth, np.full(4, 0.03), body, normals)
    np.testing.assert_allclose(got, [0.02 + LAYER_GAP, 0.0, 0.0, 0.0], atol=1e-12)
    # capped at the sample's own clearance
    got = inner_layer_margin(plan, w, items, particles, samples, cloth, np.full(4, 0.0215), body, normals)
    assert got[0] == pytest.approx(0.0215)
    # no bound vertices: nothing kept
    assert not inner_layer_margin(plan, np.ones(7), items, particles, samples, cloth, np.full(4, 0.03),
                                  body, normals).any()


def test_inner_layer_field_known_answers():
    """Over a flat skin (y = 0, normals +y, vertices every 2 cm): a top
    (item 0) whose vertex A (x = 0, 1 cm up) lies under the skirt's vertex
    there (item 1, 1.2 cm up), B (x = 0.2, 4 cm) over the skirt's vertex
    there (2 cm: a hem over the skirt), C (x = 0.6) with no skirt near and
    no decided vertex near, D (x = 0.055, 1.5 cm) with no skirt over its
    spot but A 5.5 cm away: under, as A is. A shoe's vertex (item 2,
    wholly rigid) under the skirt at x = 0 is left out. The skirt keeps
    1.3 cm (A + LAYER_GAP) within 3 cm of A's spot, 1.8 cm round D's, 0
    elsewhere; its sample at x = 0 sits 1 mm under the field at frame 0:
    allowed."""
    gx, gz = np.meshgrid(np.arange(-0.1, 0.9001, 0.02), np.arange(-0.1, 0.1001, 0.02), indexing="ij")
    body = np.stack([gx.ravel(), np.zeros(gx.size), gz.ravel()], axis=1)
    normals = np.tile([0.0, 1.0, 0.0], (len(body), 1))
    top = np.array([[0.0, 0.01, 0.0], [0.2, 0.04, 0.0], [0.6, 0.012, 0.0], [0.055, 0.015, 0.0]])
    skirt = np.array([[0.0, 0.012, 0.0], [0.2, 0.02, 0.0], [0.4, 0.005, 0.0]])
    shoe = np.array([[0.0, 0.02, 0.0]])
    items = np.concatenate([top, skirt, shoe])
    plan = SimpleNamespace(offsets=np.array([0, 4, 7, 8]),
                           items=[SimpleNamespace(name=n) for n in ("top", "skirt", "shoe")],
                           wholly_rigid=lambda: {"shoe"})
    w = np.array([0, 0, 0, 0, 1, 1, 0, 0], dtype=float)
    particles = np.array([4, 5])
    samples = np.array([[0, 0], [1, 1]])
    at = lambda x: int(np.argmin(np.linalg.norm(body - [x, 0.0, 0.0], axis=1)))  # noqa: E731
    rows, allow, field = inner_layer_field(plan, w, items, particles, samples, np.array([0.012, 0.02]),
                                           np.array([at(0.0), at(0.2)]), body, normals)
    np.testing.assert_array_equal(rows, [0, 0])
    assert field.shape == (1, len(body))
    want = {0.0: 0.01 + LAYER_GAP, 0.02: 0.01 + LAYER_GAP, 0.04: 0.015 + LAYER_GAP, 0.06: 0.015 + LAYER_GAP,
            0.08: 0.015 + LAYER_GAP, 0.1: 0.0, 0.2: 0.0, 0.6: 0.0, -0.06: 0.0}
    for x, v in want.items():
        assert field[0, at(x)] == pytest.approx(v, abs=1e-12), x
    np.testing.assert_allclose(allow, [0.01 + LAYER_GAP - 0.012, 0.0], atol=1e-12)
    # no other item bound: no field; a plan without items: none either
    rows, _, field = inner_layer_field(plan, np.ones(8), items, particles, samples, np.array([0.012, 0.02]),
                                       np.array([at(0.0), at(0.2)]), body, normals)
    assert (rows == -1).all() and not field.any()
    rows, _, field = inner_layer_field(SimpleNamespace(offsets=plan.offsets), w, items, particles, samples,
                                       np.array([0.012, 0.02]), np.array([at(0.0), at(0.2)]), body, normals)
    assert (rows == -1).all() and not field.any()


def _layered_drop(compiled=None):
    """A sheet 8 cm over a sphere's top falls onto it; a bound layer (item 0,
    shorts) lies 2 cm over the cap, too far under the sheet at frame 0 for
    :func:`inner_layer_margin` (LAYER_REACH). Returns (sheet points per
    frame, the cap's directions mask over the sheet's last frame)."""
    sp, sf = uv_sphere(24, 0.4)
    cap = sp[sp[:, 1] > 0.4 * np.cos(np.radians(25.0))]
    layer = cap / np.linalg.norm(cap, axis=1, keepdims=True) * 0.42
    sheet, faces = grid_sheet(15, 0.6, y=0.48)
    sheet[:, [0, 2]] -= 0.3
    n = len(layer)
    pts = np.concatenate([layer, sheet])
    plan = SimpleNamespace(mesh=SimpleNamespace(edges=mesh_edges(faces) + n), offsets=np.array([0, n, len(pts)]),
                           items=[SimpleNamespace(name="shorts"), SimpleNamespace(name="sheet")])
    w = np.concatenate([np.zeros(n), np.ones(len(sheet))])
    cs = ClothSolver(plan, sf, sp, pts, weights=w, attach_alpha=1e9, friction=0.5, compiled=compiled)
    frames = [cs.step(sp, pts, 1.0 / 30.0)[n:] for _ in range(30)]
    return np.array(frames), cs


def test_cloth_keeps_over_a_layer_it_falls_onto():
    frames, cs = _layered_drop()
    assert (cs.layer_row >= 0).all() and cs.layer.max() == pytest.approx(0.02 + LAYER_GAP, abs=2e-3)
    out = frames[-1]
    r = np.linalg.norm(out, axis=1)
    assert out[:, 1].min() < 0.3                     # it fell and draped round the sphere
    over = out[:, 1] / r > np.cos(np.radians(18.0))   # over the cap, away from the layer's edge
    assert over.sum() >= 20
    # over the layer (2 cm) and its gap, not at the skin's 5 mm margin
    assert (r[over] - 0.4).min() > 0.02 + LAYER_GAP - 0.003, (r[over] - 0.4).min()


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed")
def test_layered_cloth_numba_matches_numpy_twin():
    a, _ = _layered_drop(compiled=True)
    b, _ = _layered_drop(compiled=False)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)


def test_push_carry_known_answers():
    """On a grid sheet whose first row is guarded, ring r is row r: a
    uniform push s reaches row r as (1 - w) * decay^r * s, rows past
    ``rings`` and guarded rows not at all, a free vertex (w = 1) not at all."""
    n = 9
    pts, faces = grid_sheet(n)
    nb = adjacency(faces, len(pts))
    row = np.arange(len(pts)) // n
    w = np.where(row == 0, 0.0, 0.2)
    w[5 * n + 3] = 0.0                # a bound vertex past the reach: neither guarded nor carried
    w[2 * n + 4] = 1.0                # hanging free
    guarded = np.flatnonzero(row == 0)
    carry = PushCarry(nb, guarded, w, rings=4, decay=0.7)
    assert set(row[carry.rows]) == {1, 2, 3, 4}
    s = np.array([0.0, 0.01, 0.002])
    out = carry(np.tile(s, (len(guarded), 1)))
    got = dict(zip(carry.rows.tolist(), out))
    for v in carry.rows:
        r = row[v]
        want = (1.0 - w[v]) * 0.7 ** r * s
        if v == 2 * n + 4:
            want = np.zeros(3)
        np.testing.assert_allclose(got[v], want, atol=1e-12)
    # one guarded vertex pushed: only its ring-1 neighbours, by their share of the nearer ring
    one = np.zeros((len(guarded), 3))
    one[4] = s
    out = dict(zip(carry.rows.tolist(), carry(one)))
    ring1 = [v for v in carry.rows if row[v] == 1]
    moved = [v for v in ring1 if np.any(out[v] != 0)]
    assert moved and all(nb[v, 4] for v in moved)
    for v in moved:
        k = int(sum(nb[v, g] for g in guarded))
        np.testing.assert_allclose(out[v], 0.8 * 0.7 * s / k, atol=1e-12)
    with pytest.raises(ValueError, match="shift"):
        carry(np.zeros((3, 3)))


def two_item_plan(faces, n):
    """A plan of two copies of one sheet: item "skirt" (a skirt item of the
    plan's regions) and item "hair" (not one)."""
    e = mesh_edges(faces)
    items = [SimpleNamespace(name="skirt"), SimpleNamespace(name="hair")]
    return SimpleNamespace(mesh=SimpleNamespace(edges=np.concatenate([e, e + n])), items=items,
                           regions=SimpleNamespace(skirt_items={"skirt"}, body=None),
                           item_slices=lambda: [slice(0, n), slice(n, 2 * n)])


def test_set_rest_applies_to_every_loose_item():
    # hair hangs as well as a skirt: its hanging part rests as dressed on the
    # bind pose too (the ponytail dressed in a walk's first pose had edges at
    # twice their length, which the cloth then kept)
    pts, faces = grid_sheet(9, 0.8)
    n = len(pts)
    both = np.concatenate([pts, pts + [0.0, 0.0, 2.0]])
    w = np.tile(np.clip(pts[:, 0] / 0.4, 0.0, 1.0), 2)
    bp, bf = FAR_BODY
    cs = ClothSolver(two_item_plan(faces, n), bf, bp, both, weights=w)
    before = cs.rest.copy()
    cs.set_rest(both * 1.1)
    pe = cs.particles[cs.edges]
    hang = (w[pe] >= 0.5).all(axis=1)
    for item in (pe[:, 0] < n, pe[:, 0] >= n):  # the skirt, the hair
        assert (hang & item).any()
        np.testing.assert_allclose(cs.rest[hang & item], 1.1 * before[hang & item])
        np.testing.assert_array_equal(cs.rest[~hang & item], before[~hang & item])


def test_stretched_first_dress_hangs_at_its_rest_lengths():
    # a sheet pinned along x = 0 dressed stretched 1.5x along x (a posed
    # first frame's dress), its rest state unstretched: it settles at the
    # rest lengths, not at the dress's, though its targets stay stretched
    pts, faces = grid_sheet(9, 0.4)
    pts = pts[:, [1, 0, 2]] * np.array([1.0, -1.0, 1.0])  # hanging down from y = 0
    stretched = pts * np.array([1.0, 1.5, 1.0])
    w = np.clip(-pts[:, 1] / 0.1, 0.0, 1.0)
    bp, bf = FAR_BODY
    plan = two_item_plan(faces, len(pts))
    plan.items, plan.item_slices = plan.items[1:], lambda: [slice(0, len(pts))]
    plan.mesh.edges = mesh_edges(faces)
    e = mesh_edges(faces)
    rest = np.linalg.norm(pts[e[:, 0]] - pts[e[:, 1]], axis=1)
    out = {}
    for relaxed in (False, True):
        cs = ClothSolver(plan, bf, bp, stretched, weights=w)
        if relaxed:
            cs.set_rest(pts)
        for _ in range(90):
            x = cs.step(bp, stretched, 1.0 / 30.0)
        out[relaxed] = np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1) / rest
    hang = (w[e] >= 0.5).all(axis=1)   # (the part near the pins keeps the dress's lengths by design)
    assert np.percentile(out[False][hang], 99) > 1.3          # the dress's stretch kept
    assert np.percentile(out[True][hang], 99) < 1.1           # the rest lengths
