"""Motion measures (animate.measures): known answers on synthetic bodies and
items, and on a real walk against a direct computation."""
from __future__ import annotations

import json

import numpy as np
import pytest

from wearfit_usd.animate.measures import (
    MEASURES,
    MotionLimits,
    MotionMeasures,
    cast_rays,
    ray_triangle,
    worst_frames,
)


def grid(nx: int, ny: int, x0: float, y0: float, h: float, z: float = 0.0):
    """A flat (nx x ny vertices) grid at height z, triangles counter-clockwise seen from +z."""
    xs, ys = np.meshgrid(x0 + h * np.arange(nx), y0 + h * np.arange(ny), indexing="ij")
    pts = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], axis=1)
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return pts, faces


def tube(radius: float, z0: float, z1: float, n: int = 64, rings: int = 41, caps: bool = False):
    """A cylinder around the z axis (outward-facing); closed with fan caps if ``caps``."""
    ang = 2 * np.pi * (np.arange(n) + 0.5) / n
    zs = np.linspace(z0, z1, rings)
    pts = np.stack([np.tile(radius * np.cos(ang), rings), np.tile(radius * np.sin(ang), rings),
                    np.repeat(zs, n)], axis=1)
    faces = []
    for r in range(rings - 1):
        for i in range(n):
            a, b = r * n + i, r * n + (i + 1) % n
            faces += [[a, b, b + n], [a, b + n, a + n]]
    if caps:
        lo, hi = len(pts), len(pts) + 1
        pts = np.concatenate([pts, [[0, 0, z0], [0, 0, z1]]])
        top = (rings - 1) * n
        for i in range(n):
            faces += [[lo, (i + 1) % n, i], [hi, top + i, top + (i + 1) % n]]
    return pts, np.asarray(faces, dtype=np.int64)


# -- a sheet over a plane -----------------------------------------------------
H = 0.01
BODY_PLANE = grid(61, 41, -0.3 + H / 2, -0.2 + H / 2, H)          # vertices off the sheet's grid lines
SHEET = grid(41, 21, -0.2, -0.1, H, z=0.005)                      # 5 mm over the plane


def sheet_measures(items, rigid=None):
    bp, bf = BODY_PLANE
    return MotionMeasures(bf, bp, items, rigid)


def test_identity_frame_is_all_zero():
    sp_, sf = SHEET
    mm = sheet_measures([("sheet", sp_, sf)], [[np.arange(len(sp_))]])
    row = mm(BODY_PLANE[0], sp_)[0]
    assert row["stretch_p99"] == 1.0 and row["stretch_max"] == 1.0
    assert row["separation_p95_mm"] == pytest.approx(0.0, abs=1e-9)
    assert row["separation_max_mm"] == pytest.approx(0.0, abs=1e-9)
    assert row["coverage_loss_pct"] == 0.0
    assert row["rigid_mm"] == pytest.approx(0.0, abs=1e-9)
    assert row["new_pen_pct"] == 0.0
    # the covered set: the body vertices under the sheet
    bp = BODY_PLANE[0]
    under = (bp[:, 0] > -0.2) & (bp[:, 0] < 0.2) & (bp[:, 1] > -0.1) & (bp[:, 1] < 0.1)
    assert np.array_equal(np.sort(mm.covered[0]), np.flatnonzero(under))


def test_stretched_strip_stretch_and_no_coverage_loss():
    """The right half of a sheet slides 3 cm away, the strip of triangles
    between stretches over the gap: its edges across are (h + 3 cm) / h."""
    sp_, sf = SHEET
    d = 0.03
    moved = sp_.copy()
    moved[sp_[:, 0] > 0.0005, 0] += d
    row = sheet_measures([("sheet", sp_, sf)])(BODY_PLANE[0], moved)[0]
    assert row["stretch_max"] == pytest.approx((H + d) / H, rel=1e-9)
    assert row["stretch_p99"] > 1.0
    assert row["coverage_loss_pct"] == 0.0                  # stretched, still covering
    assert row["separation_max_mm"] == pytest.approx(0.0, abs=1e-6)  # still 5 mm over the plane


def test_cut_sheet_tear_uncovers_the_gap():
    """Two halves of a sheet cut along x = 0: the right one slides 3 cm,
    nothing stretches and the body under the gap shows."""
    lp, lf = grid(21, 21, -0.2, -0.1, H, z=0.005)
    rp, rf = grid(21, 21, 0.0, -0.1, H, z=0.005)
    pts = np.concatenate([lp, rp])
    faces = np.concatenate([lf, rf + len(lp)])
    d = 0.03
    moved = pts.copy()
    moved[len(lp):, 0] += d
    mm = sheet_measures([("sheet", pts, faces)])
    row = mm(BODY_PLANE[0], moved)[0]
    bp = BODY_PLANE[0][mm.covered[0]]
    expected = 100.0 * np.mean((bp[:, 0] > 0.0) & (bp[:, 0] < d))
    assert expected > 5
    assert row["coverage_loss_pct"] == pytest.approx(expected)
    assert row["stretch_max"] == pytest.approx(1.0)


def test_new_penetrations_fraction():
    sp_, sf = SHEET
    moved = sp_.copy()
    sink = sp_[:, 0] < -0.1005                     # 10 of 41 columns pushed 1 cm through the plane
    moved[sink, 2] = -0.01
    row = sheet_measures([("sheet", sp_, sf)])(BODY_PLANE[0], moved)[0]
    assert row["new_pen_pct"] == pytest.approx(100.0 * sink.mean())


def test_item_far_from_the_body_has_no_separation_and_no_coverage():
    far, ff = grid(5, 5, -0.02, -0.02, H, z=0.2)   # 20 cm over the plane
    row = sheet_measures([("far", far, ff)])(BODY_PLANE[0], far + [0.0, 0.0, 0.05])[0]
    assert row["separation_p95_mm"] is None and row["coverage_loss_pct"] is None and row["rigid_mm"] is None


# -- a fold: another part of the body over the sheet ---------------------------
def box(x0, x1, y0, y1, z0, z1):
    """A closed box (outward-facing triangles, edges <= 1 cm like the plane's)."""
    import trimesh
    m = trimesh.creation.box(bounds=[[x0, y0, z0], [x1, y1, z1]])
    v, f = trimesh.remesh.subdivide_to_size(m.vertices, m.faces, max_edge=0.01)
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def plane_and_box(frame_box):
    """The plane with a box as another part of the same body, 1.2 m to the
    side in the static dress: (faces, static points, frame points)."""
    bp, bf = BODY_PLANE
    p1, f1 = box(*frame_box)
    faces = np.concatenate([bf, f1 + len(bp)])
    return faces, np.concatenate([bp, p1 + [1.2, 0.0, 0.0]]), np.concatenate([bp, p1])


IN_BOX = (-0.1045, 0.0045, -0.3, 0.3)        # over 11 of the sheet's 41 columns, across the sheet


def torn_under_box(mm, body0, body1):
    """The sheet's columns under the box lifted 30 cm (torn away) on the
    frame body1: the plane's probes under the box are folded, the rest of
    the tear (its triangles' edges outside the box) lost. Returns (the torn
    sheet, which statically covered probes lie under the box)."""
    sp_, _ = SHEET
    torn = sp_.copy()
    torn[(sp_[:, 0] > IN_BOX[0]) & (sp_[:, 0] < IN_BOX[1]), 2] += 0.3
    row = mm(body1, torn)[0]
    pv = body0[mm.covered[0]]
    in_box = (pv[:, 0] > IN_BOX[0]) & (pv[:, 0] < IN_BOX[1])
    raw = mm.coverage_loss(0, body1, mm.normals(body1), torn, folds=False)
    assert row["coverage_folded_pct"] == pytest.approx(100.0 * in_box.mean())
    assert row["coverage_loss_pct"] == pytest.approx(raw - row["coverage_folded_pct"])
    assert row["coverage_loss_pct"] > 0.0
    return torn, in_box


def test_a_part_of_the_body_pressed_over_the_sheet_is_a_fold_not_loss_or_penetration():
    """A box (an arm) comes down over the plane (the torso) and the sheet
    between them: the sheet's vertices inside the box are not new
    penetrations, the plane's vertices inside the box not coverage loss,
    both reported as folded; the same box hovering 2 cm over the sheet is
    no fold."""
    sp_, sf = SHEET
    faces, body0, body1 = plane_and_box((*IN_BOX, -0.02, 0.008))
    mm = MotionMeasures(faces, body0, [("sheet", sp_, sf)])
    inside = (sp_[:, 0] > IN_BOX[0]) & (sp_[:, 0] < IN_BOX[1])
    assert inside.sum() == 11 * 21
    row = mm(body1, sp_)[0]                      # the sheet stays, 3 mm inside the box's top
    assert row["new_pen_pct"] == 0.0
    assert row["pen_folded_pct"] == pytest.approx(100.0 * inside.mean())
    assert row["coverage_loss_pct"] == 0.0       # the sheet still meets every ray
    # the sheet torn away under the box: the plane inside the box is folded, the rest of the tear lost
    torn, in_box = torn_under_box(mm, body0, body1)
    assert in_box.sum() == 10 * 20
    # the box 2 cm over the plane (12 mm beyond the sheet's 5 mm and the 5 mm margin): no fold
    faces, body0, body2 = plane_and_box((*IN_BOX, 0.02, 0.06))
    mm = MotionMeasures(faces, body0, [("sheet", sp_, sf)])
    row = mm(body2, torn)[0]
    assert row["coverage_folded_pct"] == 0.0
    assert row["coverage_loss_pct"] == pytest.approx(mm.coverage_loss(0, body2, mm.normals(body2), torn,
                                                                      folds=False))
    assert row["coverage_loss_pct"] > 100.0 * in_box.mean()
    sunk = sp_.copy()
    sunk[inside, 2] = 0.03                       # pushed up into the hovering box
    row = mm(body2, sunk)[0]
    assert row["pen_folded_pct"] == 0.0 and row["new_pen_pct"] == pytest.approx(100.0 * inside.mean())


def test_a_probe_deep_inside_another_part_is_a_fold_however_far_its_ray_leaves():
    """A deep box (a torso the skinning sinks a shoulder into) comes down
    over the plane and the torn sheet: the plane's rays inside it leave the
    box 25 cm up, beyond the 8 cm coverage reach, and are folded all the
    same, not lost."""
    sp_, sf = SHEET
    faces, body0, body1 = plane_and_box((*IN_BOX, -0.2, 0.25))
    mm = MotionMeasures(faces, body0, [("sheet", sp_, sf)])
    torn, in_box = torn_under_box(mm, body0, body1)   # torn through the box's top
    # the same rays outside any box meet nothing and leave nothing: lost
    faces, body0, body2 = plane_and_box((*IN_BOX, 0.35, 0.6))
    mm = MotionMeasures(faces, body0, [("sheet", sp_, sf)])
    row = mm(body2, torn)[0]
    assert row["coverage_folded_pct"] == 0.0
    assert row["coverage_loss_pct"] >= 100.0 * in_box.mean()


# -- a sleeve on a limb ---------------------------------------------------------
LIMB = tube(0.05, 0.0, 0.6, rings=61, caps=True)                  # 1 cm rings
SLEEVE = tube(0.055, 0.205, 0.395, rings=20)                      # ring heights off the limb's


def sleeve_measures():
    lp, lf = LIMB
    return MotionMeasures(lf, lp, [("sleeve", *SLEEVE)])


def test_loosened_sleeve_separates_by_the_added_radius():
    sp_, _ = SLEEVE
    mm = sleeve_measures()
    loose = sp_.copy()
    loose[:, :2] *= 0.075 / 0.055                  # 2 cm further out
    row = mm(LIMB[0], loose)[0]
    assert row["separation_p95_mm"] == pytest.approx(20.0, abs=0.05)
    assert row["separation_max_mm"] == pytest.approx(20.0, abs=0.05)
    assert row["coverage_loss_pct"] == 0.0         # 2.5 cm out: still within 8 cm


def test_sleeve_slid_along_the_limb_uncovers_what_it_left():
    sp_, _ = SLEEVE
    mm = sleeve_measures()
    s = 0.1
    row = mm(LIMB[0], sp_ + [0.0, 0.0, s])[0]
    z = LIMB[0][mm.covered[0], 2]
    assert np.all((z > 0.2) & (z < 0.4))
    expected = 100.0 * np.mean(z < 0.205 + s)
    assert 40 < expected < 60
    assert row["coverage_loss_pct"] == pytest.approx(expected)
    assert row["separation_max_mm"] == pytest.approx(0.0, abs=0.1)   # same radius


def test_sleeve_pulled_off_the_limb():
    sp_, _ = SLEEVE
    mm = sleeve_measures()
    row = mm(LIMB[0], sp_ + [0.0, 0.0, 0.4])[0]   # z 0.605 .. 0.795: beyond the limb's end
    assert row["coverage_loss_pct"] == 100.0
    # each vertex now stands off the cap's rim: sqrt(5 mm^2 + dz^2) - 5 mm more
    dz = sp_[:, 2] + 0.4 - 0.6
    rim = np.sqrt((0.055 - 0.05 * np.cos(np.pi / 64)) ** 2 + dz ** 2) - (0.055 - 0.05 * np.cos(np.pi / 64))
    assert row["separation_max_mm"] == pytest.approx(1000 * rim.max(), rel=0.01)


def test_hanging_skirt_swung_away_still_covers_and_does_not_separate():
    """A sleeve-like skirt round the limb, marked hanging: swung 20 cm
    sideways (beyond the 8 cm reach) it still covers the limb on the side it
    swung to and the limb shows only where it came out through it; it has
    no contact vertices, so no separation. Unmarked, the same frame loses
    every body vertex farther than 8 cm from it."""
    lp, lf = LIMB
    sp_, sf = SLEEVE
    skirt = sp_.copy()
    skirt[:, :2] *= 0.09 / 0.055                    # 4 cm ease all round: covers the limb statically
    swung = skirt + [0.02, 0.0, 0.0]                # 2 cm sideways: the limb still inside
    hang = np.ones(len(skirt), dtype=bool)
    plain = MotionMeasures(lf, lp, [("skirt", skirt, sf)])
    loose = MotionMeasures(lf, lp, [("skirt", skirt, sf)], hanging=hang)
    assert np.array_equal(plain.covered[0], loose.covered[0]) and len(loose.covered[0]) > 100
    assert plain.contact_mask.sum() == 0 or loose.contact_mask.sum() == 0
    row = loose(lp, swung)[0]
    assert row["coverage_loss_pct"] == 0.0 and row["separation_p95_mm"] is None
    # swung 12 cm: the limb's side facing away from the swing comes out of it;
    # the rest still meets the skirt along its normal, most beyond 8 cm
    far = skirt + [0.12, 0.0, 0.0]
    o = lp[loose.covered[0]]
    d = o[:, :2] / np.linalg.norm(o[:, :2], axis=1, keepdims=True)
    rel = o[:, :2] - [0.12, 0.0]
    b, c = np.sum(rel * d, axis=1), np.sum(rel * rel, axis=1) - 0.09 ** 2
    disc = b * b - c
    t_far = -b + np.sqrt(np.maximum(disc, 0.0))               # the exit through the skirt's wall
    meets = (disc > 0) & (t_far > 0.0) & (t_far < 0.5)
    row = loose(lp, far)[0]
    assert 20.0 < 100.0 * np.mean(~meets) < 80.0
    assert row["coverage_loss_pct"] == pytest.approx(100.0 * np.mean(~meets), abs=3.0)
    assert plain(lp, far)[0]["coverage_loss_pct"] > row["coverage_loss_pct"] + 10.0


def test_hanging_vertices_are_not_contacts():
    sp_, sf = SLEEVE
    lp, lf = LIMB
    hang = sp_[:, 2] < 0.3                          # the lower half hangs
    mm = MotionMeasures(lf, lp, [("sleeve", sp_, sf)], hanging=hang)
    moved = sp_.copy()
    moved[hang, :2] *= 0.085 / 0.055                # the hanging half 3 cm out
    row = mm(lp, moved)[0]
    assert row["separation_max_mm"] == pytest.approx(0.0, abs=0.1)
    row = sleeve_measures()(lp, moved)[0]
    assert row["separation_max_mm"] == pytest.approx(30.0, abs=0.1)


# -- a rigid part ---------------------------------------------------------------
def test_rigid_part_bent_and_moved():
    plate, pf = grid(21, 6, -0.1, -0.025, H, z=0.01)
    mm = sheet_measures([("plate", plate, pf)], [[np.arange(len(plate))]])
    # a similarity (turned, scaled, moved) keeps its shape: 0 mm
    a = 0.3
    rot = np.array([[np.cos(a), np.sin(a), 0], [-np.sin(a), np.cos(a), 0], [0, 0, 1]])
    sim = 1.1 * plate @ rot + [0.01, 0.02, 0.003]
    assert mm(BODY_PLANE[0], sim)[0]["rigid_mm"] == pytest.approx(0.0, abs=1e-6)
    # the front half bent up about x = 0 by 20 degrees: tip lifted 34 mm
    b = np.radians(20)
    bent = plate.copy()
    front = plate[:, 0] > 0
    x = plate[front, 0]
    bent[front, 0] = x * np.cos(b)
    bent[front, 2] = 0.01 + x * np.sin(b)
    tip = 0.1 * np.sin(b)
    r_bent = mm(BODY_PLANE[0], bent)[0]["rigid_mm"]
    assert 0.1 * 1000 * tip < r_bent < 1000 * tip
    # bent further: further from its similarity
    bent2 = plate.copy()
    b2 = np.radians(40)
    bent2[front, 0] = x * np.cos(b2)
    bent2[front, 2] = 0.01 + x * np.sin(b2)
    assert mm(BODY_PLANE[0], bent2)[0]["rigid_mm"] > 1.5 * r_bent


# -- the ray caster -------------------------------------------------------------
def test_layer_coming_through_another_item():
    """Two sheets over the plane: an inner one at 5 mm, an outer one at 15 mm
    (offset by half a cell). Statically every inner vertex is under the
    outer one (through 0 %); lift the inner sheet's left half to 25 mm and
    that half comes through it (50 %); the outer sheet is under nothing
    (None). A single item has no layers at all."""
    sp_, sf = SHEET
    outer = sp_ + [H / 2, H / 2, 0.01]
    mm = sheet_measures([("inner", sp_, sf), ("outer", outer, sf)])
    both = np.concatenate([sp_, outer])
    rows = mm(BODY_PLANE[0], both)
    assert rows[0]["through_pct"] == 0.0 and rows[1]["through_pct"] is None
    assert len(mm.under) == len(sp_)
    moved = both.copy()
    left = sp_[:, 0] < -1e-9
    moved[:len(sp_)][left, 2] = 0.025
    got = mm(BODY_PLANE[0], moved)[0]["through_pct"]
    assert got == pytest.approx(100.0 * left.mean(), abs=1e-9)
    assert 45.0 < got < 55.0
    assert sheet_measures([("inner", sp_, sf)])(BODY_PLANE[0], sp_)[0]["through_pct"] is None


@pytest.mark.parametrize("small_rays", [0, 10**9], ids=["kd-trees", "pairwise boxes"])
def test_cast_rays_matches_brute_force(monkeypatch, small_rays):
    from wearfit_usd.geometry import rays
    monkeypatch.setattr(rays, "SMALL_RAYS", small_rays)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.1, 0.1, (300, 3))
    faces = rng.integers(0, 300, (200, 3))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    orig = rng.uniform(-0.15, 0.15, (400, 3))
    dirs = rng.normal(size=(400, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    got = cast_rays(orig, dirs, pts, faces, -0.005, 0.08, chunk=97)
    r = np.repeat(np.arange(len(orig)), len(faces))
    t = np.tile(np.arange(len(faces)), len(orig))
    hit, tt = ray_triangle(orig[r], dirs[r], pts[faces[t, 0]], pts[faces[t, 1]], pts[faces[t, 2]], -0.005, 0.08)
    hit = hit.reshape(len(orig), len(faces))
    assert np.array_equal(got >= 0, hit.any(axis=1))
    assert hit.any(axis=1).sum() > 20
    tt = np.where(hit, np.abs(tt.reshape(len(orig), len(faces))), np.inf)
    rows = np.flatnonzero(got >= 0)
    assert np.allclose(tt[rows, got[rows]], tt[rows].min(axis=1))


# -- limits and worst frames ----------------------------------------------------
def test_worst_frames_and_limits():
    series = {"a": {k: [] for k in MEASURES}}
    for v in ([1.0, 1.0, 0.0, 0.0, 0.5, None, 0.0], [1.2, 1.3, 3.0, 4.0, 2.5, None, 0.2]):
        for k, x in zip(MEASURES, v):
            series["a"][k].append(x)
    worst = worst_frames(series, [0, 5])
    assert worst["a"]["stretch_p99"] == {"value": 1.2, "frame": 5}
    assert worst["a"]["rigid_mm"] == {"value": None, "frame": None}
    bad = MotionLimits().violations(worst)
    assert len(bad) == 2 and "stretch_p99" in bad[0] and "coverage_loss_pct" in bad[1]
    assert MotionLimits(stretch_p99=2.0, coverage_loss_pct=3.0).violations(worst) == []


# -- real data --------------------------------------------------------------------
def test_walk_report_matches_a_direct_computation(usd_dir, bvh_dir, tmp_path):
    """animate's measures on ref_female / body_female_thin, 20 walk frames,
    equal a direct computation on the written shot's last frame."""
    from pxr import Usd, UsdGeom

    from wearfit_usd.animate.loose import cloth_weights
    from wearfit_usd.animate.try_on import AnimateOptions, animate, dress_items
    from wearfit_usd.cli import main
    from wearfit_usd.dress.item_weights import rigid_pieces
    from wearfit_usd.dress.plan import plan as plan_dress
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.io.usd import read_character
    from wearfit_usd.motion.floor import place_on_floor
    from wearfit_usd.motion.retarget import retarget
    from wearfit_usd.motion.skinning import skin_points, skinning_matrices
    from wearfit_usd.transforms import transform_points
    ref = read_character(usd_dir / "ref_female.usda")
    tgt = read_character(usd_dir / "body_female_thin.usdc")
    clip = bvh_dir / "cmu_07_01_walk.bvh"
    shot = tmp_path / "walk.usdc"
    report = tmp_path / "walk.json"
    rc = main(["animate", str(usd_dir / "ref_female.usda"), str(usd_dir / "body_female_thin.usdc"), str(clip),
               "--start", "1", "--end", "81", "-o", str(shot), "--report", str(report), "-q"])
    assert rc == 0
    rep = json.loads(report.read_text())
    assert rep["measured_frames"] == list(range(20))
    names = [m.name for m in ref.items]
    assert list(rep["motion_worst"]) == names
    for name in names:
        for key in MEASURES:
            series = rep["motion_per_frame"][name][key]
            assert len(series) == 20
            vals = [v for v in series if v is not None]
            if vals:
                assert rep["motion_worst"][name][key]["value"] == max(vals)
    shoes = rep["motion_worst"]["shoes02"]
    assert np.isfinite(shoes["coverage_loss_pct"]["value"]) and 0 <= shoes["coverage_loss_pct"]["value"] <= 100
    assert shoes["stretch_max"]["value"] >= shoes["stretch_p99"]["value"] >= 1.0
    assert rep["motion_worst"]["female_casualsuit01"]["separation_p95_mm"]["value"] is not None
    # direct: the static dress, the body skinned at the last frame, the items read back
    dressed = dress_items(ref, tgt)
    mm = MotionMeasures(tgt.body.faces, tgt.body.points, [(m.name, m.points, m.faces) for m in dressed.items],
                        rigid_pieces(dressed, tgt), hanging=cloth_weights(plan_dress(ref)) >= 0.5)
    rt = retarget(read_bvh(clip), tgt.skeleton, start=1, end=81, fps=30.0)
    rt, _ = place_on_floor(rt, tgt.skeleton, tgt.body, "auto")  # as animate's default --floor auto
    f = 19
    body_f = skin_points(tgt.body.points, tgt.body.joint_indices, tgt.body.joint_weights,
                         skinning_matrices(tgt.skeleton.bind_world, rt.world[f]))
    stage = Usd.Stage.Open(str(shot))
    shot_char = read_character(shot)
    pts = np.concatenate([np.array(UsdGeom.Mesh(stage.GetPrimAtPath(f"/Root/Items/{n}")).GetPointsAttr().Get(f))
                          for n in names])
    pts = transform_points(pts.astype(np.float64), shot_char.to_internal)
    direct = {r["item"]: r for r in mm(body_f, pts)}
    for name in names:
        got = {k: rep["motion_per_frame"][name][k][f] for k in MEASURES}
        want = direct[name]
        for k in ("stretch_p99", "stretch_max"):
            assert got[k] == pytest.approx(want[k], rel=2e-3), (name, k)
        for k in ("separation_p95_mm", "separation_max_mm", "rigid_mm"):
            if want[k] is None:
                assert got[k] is None
            else:
                assert got[k] == pytest.approx(want[k], abs=0.05), (name, k)
        for k in ("coverage_loss_pct", "new_pen_pct"):
            if want[k] is not None:
                assert got[k] == pytest.approx(want[k], abs=0.2), (name, k)   # float32 points on file
    # --strict on the first 2 frames: fails exactly when its report has a
    # figure over a limit, with the shot written all the same; and measuring
    # leaves the shot as it is without
    strict, strict_rep = tmp_path / "strict.usdc", tmp_path / "strict.json"
    rc = main(["animate", str(usd_dir / "ref_female.usda"), str(usd_dir / "body_female_thin.usdc"), str(clip),
               "--start", "1", "--end", "9", "-o", str(strict), "--strict", "--report", str(strict_rep), "-q"])
    worst = json.loads(strict_rep.read_text())["motion_worst"]
    assert rc == (1 if MotionLimits().violations(worst) else 0)
    assert strict.exists()
    plain = tmp_path / "plain.usdc"
    animate(ref, tgt, read_bvh(clip), plain, AnimateOptions(start=1, end=9))
    a, b = Usd.Stage.Open(str(strict)), Usd.Stage.Open(str(plain))
    for n in names:
        for t in (0, 1):
            pa = np.array(UsdGeom.Mesh(a.GetPrimAtPath(f"/Root/Items/{n}")).GetPointsAttr().Get(t))
            pb = np.array(UsdGeom.Mesh(b.GetPrimAtPath(f"/Root/Items/{n}")).GetPointsAttr().Get(t))
            assert np.array_equal(pa, pb)


# -- a low-poly body: coverage probed over its triangles ------------------------
def test_coverage_probes_are_a_lattice_inside_each_large_triangle():
    from wearfit_usd.animate.measures import coverage_probes
    pts = np.array([[0.0, 0, 0], [0.10, 0, 0], [0.0, 0.10, 0], [0.0, 0, 0.01], [0.01, 0, 0.01], [0, 0.01, 0.01]])
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    tri, bary = coverage_probes(pts, faces, 0.02)
    # the 10 cm x 14 cm triangle: ceil(14.1 / 2) = 8 steps, (8-1)(8-2)/2 = 21 interior points; the 1 cm one none
    assert len(tri) == 21 and set(tri.tolist()) == {0}
    np.testing.assert_allclose(bary.sum(axis=1), 1.0)
    assert bary.min() >= 1 / 8 - 1e-12
    p = np.einsum("sc,sci->si", bary, pts[faces[tri]])
    d = np.linalg.norm(p[:, None] - p[None], axis=2) + np.eye(len(p))
    assert d.min(axis=1).max() <= 0.02 + 1e-12   # each has a neighbour within the spacing
    assert len(coverage_probes(pts, faces, 1.0)[0]) == 0


def test_a_low_poly_body_measures_coverage_over_its_faces():
    """A 40 cm plane of two triangles (median edge 40 cm): a 6 cm patch 5 mm
    over its middle covers no body vertex, yet it covers the body; moved 10
    cm up it covers nothing (loss 100 %), slid 2 cm along the plane half of
    its probes stay covered."""
    body = np.array([[-0.2, -0.2, 0.0], [0.2, -0.2, 0.0], [0.2, 0.2, 0.0], [-0.2, 0.2, 0.0]])
    bf = np.array([[0, 1, 2], [0, 2, 3]])
    patch, pf = grid(7, 7, -0.03, -0.03, 0.01, z=0.005)
    mm = MotionMeasures(bf, body, [("patch", patch, pf)])
    n_probe = len(mm.covered[0])
    assert n_probe >= 4 and mm.covered[0].min() >= len(body)   # probes on the faces, no vertex
    assert mm(body, patch)[0]["coverage_loss_pct"] == pytest.approx(0.0)
    assert mm(body, patch + [0.0, 0.0, 0.1])[0]["coverage_loss_pct"] == pytest.approx(100.0)
    slid = mm(body, patch + [0.03, 0.0, 0.0])[0]["coverage_loss_pct"]
    assert 20.0 < slid < 80.0
