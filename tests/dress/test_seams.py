"""Seams between body regions: blend shares along the item, blended bindings.

Known answers on a strip of vertices crossing a region line, the blended
binding's exactness and rigid motion, and the plan of the demo's one-piece
suit (its jacket bound to the torso, its sleeves blended into it, only its
skirt smoothed as a skirt).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from wearfit_usd.dress import regions as R
from wearfit_usd.dress.binding import bind, blend_rows
from wearfit_usd.dress.seams import seam_shares
from wearfit_usd.transforms import matrix_from_quat, quat_normalize


def _strip(n=41, step=0.01):
    """n vertices along x at ``step`` apart (x from -0.2 to 0.2), chained."""
    x = (np.arange(n) - n // 2) * step
    pts = np.stack([x, np.zeros(n), np.zeros(n)], axis=1)
    e = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    return pts, e


def test_shares_known_answers_across_a_line():
    pts, e = _strip()
    labels = np.where(pts[:, 0] < 0, R.TORSO, R.LEFT_ARM)
    other, share = seam_shares(pts, e, labels, band=0.08)
    # phi = (1 - d / band)^2 of the other label, share = phi / (1 + phi)
    for i, x in enumerate(pts[:, 0]):
        d = x + 0.01 if x >= 0 else -x  # to the nearest vertex of the other label (at -0.01 or 0)
        phi = max(0.0, 1.0 - d / 0.08) ** 2
        assert share[i] == pytest.approx(phi / (1.0 + phi), abs=1e-9), (x, share[i])
        if phi > 0:
            assert other[i] == (R.LEFT_ARM if x < 0 else R.TORSO)
        else:
            assert other[i] == -1
    # continuous: next to the line both sides nearly halves, beyond the band nothing
    assert share[np.argmin(np.abs(pts[:, 0] + 0.01))] > 0.4
    assert share[np.argmin(np.abs(pts[:, 0]))] > 0.4
    assert np.all(share[np.abs(pts[:, 0]) > 0.09] == 0.0)
    assert np.all(np.diff(share[pts[:, 0] >= 0]) <= 1e-12)  # fades away from the line


def test_regions_that_do_not_meet_do_not_blend():
    pts, e = _strip()
    # a skirt next to a leg, the head next to a leg
    for a, b in ((R.HIPS, R.LEFT_LEG), (R.HEAD, R.RIGHT_LEG)):
        labels = np.where(pts[:, 0] < 0, a, b)
        other, share = seam_shares(pts, e, labels, band=0.08)
        assert np.all(other == -1) and np.all(share == 0.0)
    # one label: nothing; band 0: nothing
    assert np.all(seam_shares(pts, e, np.full(len(pts), R.TORSO))[1] == 0.0)
    assert np.all(seam_shares(pts, e, np.where(pts[:, 0] < 0, R.TORSO, R.HEAD), band=0.0)[1] == 0.0)


def test_the_two_legs_blend_over_the_crotch_band_only():
    """Pants join the legs in one crotch seam: the sides blend there (half
    and half on the line), over PAIR_BAND (3 cm), not the 8 cm band."""
    from wearfit_usd.dress.seams import PAIR_BAND
    band = PAIR_BAND[frozenset((R.LEFT_LEG, R.RIGHT_LEG))]
    assert band == pytest.approx(0.03)
    pts, e = _strip()
    labels = np.where(pts[:, 0] < 0, R.RIGHT_LEG, R.LEFT_LEG)
    other, share = seam_shares(pts, e, labels, band=0.08)
    for i, x in enumerate(pts[:, 0]):
        d = x + 0.01 if x >= 0 else -x
        phi = max(0.0, 1.0 - d / band) ** 2
        assert share[i] == pytest.approx(phi / (1.0 + phi), abs=1e-9), (x, share[i])
        assert other[i] == ((R.LEFT_LEG if x < 0 else R.RIGHT_LEG) if phi > 0 else -1)
    assert share[np.argmin(np.abs(pts[:, 0]))] > 0.3  # 1 cm from the other side's first vertex
    assert np.all(share[np.abs(pts[:, 0]) >= 0.03] == 0.0)  # a trouser leg's inside keeps to its leg


def test_pants_crotch_seam_sides_follow_both_legs(ref_female_longskirt):
    """The hot pants of ref_female_longskirt: the vertices on their crotch
    seam are bound to the left and the right thigh, half and half (before,
    each side followed its own thigh and the seam opened 5 cm in a walk)."""
    from wearfit_usd.dress.plan import plan as make_plan
    p = make_plan(ref_female_longskirt)
    i = [m.name for m in p.items].index("female_casualsuit02")
    sl = p.item_slices()[i]
    lab = p.regions.bind[sl]
    pts = p.items[i].points
    seam = (np.abs(pts[:, 0]) < 0.002) & np.isin(lab, [R.LEFT_LEG, R.RIGHT_LEG])
    assert seam.sum() >= 10
    body = ref_female_longskirt.body
    rows = np.arange(sl.start, sl.stop)[seam]
    tri = p.binding.triangles[rows]
    w = p.binding.weights[rows]
    cx = body.points[body.faces[tri]].mean(axis=2)[..., 0]
    left = (w * (cx > 0)).sum(axis=1)
    # each side alone gave 0 or 1; a few seam vertices are farther than the band from the other side
    assert np.mean((left > 0.1) & (left < 0.9)) > 0.8, left
    assert np.all((left > 0.0) & (left < 1.0)), left


def test_distances_follow_the_item_not_space():
    """Two strands 1 cm apart in space, joined only at one end: the labels
    of one strand do not leak across the gap to the other."""
    n = 21
    x = np.arange(n) * 0.01
    a = np.stack([x, np.zeros(n), np.zeros(n)], axis=1)
    b = a + [0.0, 0.01, 0.0]
    pts = np.concatenate([a, b])
    e = np.concatenate([np.stack([np.arange(n - 1), np.arange(1, n)], 1),
                        np.stack([np.arange(n - 1), np.arange(1, n)], 1) + n, [[n - 1, 2 * n - 1]]])
    labels = np.r_[np.full(n, R.TORSO), np.full(n, R.RIGHT_ARM)]
    other, share = seam_shares(pts, e, labels, band=0.05)
    assert share[0] == 0.0 and share[n] == 0.0  # 1 cm apart in space, 0.21 m along the item
    # joined here by a 1 cm edge: phi = (1 - 0.01 / 0.05)^2
    assert share[n - 1] == pytest.approx(0.64 / 1.64) and share[2 * n - 1] == pytest.approx(0.64 / 1.64)


def _sphere():
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    return np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)


def test_blended_binding_is_exact_and_rigid():
    body, faces = _sphere()
    rng = np.random.default_rng(3)
    items = rng.normal(size=(200, 3))
    items = items / np.linalg.norm(items, axis=1, keepdims=True) * 0.32
    left = body[faces].mean(axis=1)[:, 0] < 0
    first = bind(body, faces, items, k=5, candidate_mask=left)
    rows = np.arange(0, 200, 2)
    second = bind(body, faces, items[rows], k=4, candidate_mask=~left)
    share = np.linspace(0.0, 0.5, len(rows))
    b = blend_rows(first, body, items, rows, second, share)
    assert b.triangles.shape == (200, 9)
    np.testing.assert_allclose(b.weights.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(b.weights[rows, 5:].sum(axis=1), share, atol=1e-12)
    assert np.all(b.weights[1::2, 5:] == 0.0)
    assert np.abs(b.evaluate(body) - items).max() < 1e-9
    rot = matrix_from_quat(quat_normalize(np.array([0.8, 0.3, -0.2, 0.4])))
    t = np.array([0.1, 1.0, -0.4])
    np.testing.assert_allclose(b.evaluate(body @ rot + t), items @ rot + t, atol=1e-9)
    # the rows it did not blend evaluate as before
    moved = body * [1.2, 0.9, 1.0]
    np.testing.assert_allclose(b.evaluate(moved)[1::2], first.evaluate(moved)[1::2], atol=1e-12)
    with pytest.raises(ValueError):
        blend_rows(first, body, items, rows[:-1], second, share)


def test_suit_plan_binds_the_jacket_to_the_torso_and_blends_its_sleeves():
    from wearfit_usd.demo.samples import make_body, make_garments
    from wearfit_usd.dress.plan import SKIRT_TOP
    from wearfit_usd.dress.plan import plan as make_plan
    ref = make_body("reference")
    suit = next(m for m in make_garments(ref) if m.name == "suit")
    p = make_plan(replace(ref, items=[suit]))
    lab = p.regions.bind
    crotch = ref.body.points[p.regions.body == R.TORSO, 1].min()
    hips = lab == R.HIPS
    # the skirt part hangs from the hips, the jacket above is a top
    assert hips.sum() > 300 and np.all(p.ref_points[hips, 1] < crotch + SKIRT_TOP)
    above = p.ref_points[:, 1] > crotch + SKIRT_TOP + 0.02
    assert np.all(np.isin(lab[above], [R.TORSO, R.LEFT_ARM, R.RIGHT_ARM, R.HEAD]))
    # only the skirt part is smoothed as a skirt (fully loose): the sleeves are not
    arms = np.isin(lab, [R.LEFT_ARM, R.RIGHT_ARM])
    assert np.all(p.looseness[hips] == 1.0) and p.looseness[arms].mean() < 0.5
    # the sleeves' vertices next to the jacket follow both: more triangles, weight on both regions
    tri_region = p.regions.triangle[p.binding.triangles]
    w = p.binding.weights
    on_torso = np.sum(w * np.isin(tri_region, [R.TORSO]), axis=1)
    seam = arms & (on_torso > 0.05)
    assert seam.sum() > 40
    assert np.all(on_torso[arms] <= 0.5 + 1e-9)
