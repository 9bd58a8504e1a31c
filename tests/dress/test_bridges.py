"""Bridges: where neighbouring item vertices follow different joints, the
item's displacement is smoothed over a band (dress.bridges)."""
import numpy as np
import pytest
import scipy.sparse as sp

from wearfit_usd.dress.bridges import BRIDGE_BAND, bridge_weights, item_joint_weights
from wearfit_usd.dress.plan import plan


def test_item_joint_weights_blend_the_bound_triangles_corners():
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    # vertex joint weights: 0 -> joint 0; 1 -> half 0, half 1; 2 -> joint 1; 3 -> joint 2
    ji = np.array([[0, 0], [0, 1], [1, 0], [2, 0]])
    jw = np.array([[1.0, 0.0], [0.5, 0.5], [1.0, 0.0], [1.0, 0.0]])
    tri = np.array([[0, 0], [0, 1]])
    coef = np.array([[1.0, 0.0], [0.25, 0.75]])
    om = item_joint_weights(tri, coef, faces, ji, jw, 3).toarray()
    t0 = np.array([1.5, 1.5, 0.0]) / 3  # triangle 0's corners: (1,0,0), (.5,.5,0), (0,1,0)
    t1 = np.array([0.5, 1.5, 1.0]) / 3  # triangle 1's: (.5,.5,0), (0,0,1), (0,1,0)
    np.testing.assert_allclose(om[0], t0)
    np.testing.assert_allclose(om[1], 0.25 * t0 + 0.75 * t1)
    np.testing.assert_allclose(om.sum(axis=1), 1.0)
    with pytest.raises(ValueError, match="coefficients"):
        item_joint_weights(tri, coef[:, :1], faces, ji, jw, 3)


def _chain(jump_at=5, gap=0.002, n=12, step=0.01):
    """n points along x, ``step`` apart except ``gap`` between ``jump_at``
    and the next; joint weight 0 on the left of the gap, joint 1 on the right."""
    x = np.cumsum(np.r_[0.0, [gap if i == jump_at else step for i in range(n - 1)]])
    pts = np.c_[x, np.zeros(n), np.zeros(n)]
    e = np.c_[np.arange(n - 1), np.arange(1, n)]
    om = sp.csr_matrix(np.c_[np.arange(n) <= jump_at, np.arange(n) > jump_at].astype(float))
    return pts, e, om


def test_a_jump_of_joints_over_a_short_edge_is_a_bridge_with_a_band():
    pts, e, om = _chain()
    w = bridge_weights(om, pts, e)
    # the gap's edge: |omega_5 - omega_6|_1 = 2 over 2 mm: 1000 per metre
    assert w[5] == 1.0 and w[6] == 1.0
    band = BRIDGE_BAND
    for v, d in [(4, 0.01), (3, 0.02), (7, 0.01), (8, 0.02)]:
        np.testing.assert_allclose(w[v], (1.0 - d / band) ** 2)
    assert np.all(w[[0, 1, 2, 9, 10, 11]] == 0.0)  # 3 cm and more from the bridge


def test_a_gradual_change_is_no_bridge():
    # the same joint change spread over 11 edges of 1 cm: 2 / 0.11 m = 18 per metre at most per edge
    n = 12
    pts = np.c_[np.arange(n) * 0.01, np.zeros(n), np.zeros(n)]
    e = np.c_[np.arange(n - 1), np.arange(1, n)]
    t = np.arange(n) / (n - 1)
    om = sp.csr_matrix(np.c_[1 - t, t])
    assert np.all(bridge_weights(om, pts, e) == 0.0)
    # a sharper gradient than the threshold is one: 2 per 1 cm = 200 per metre
    pts2, e2, om2 = _chain(gap=0.01)
    assert bridge_weights(om2, pts2, e2)[5] == 1.0
    with pytest.raises(ValueError, match="rows"):
        bridge_weights(om[:5], pts, e)


def test_the_hot_pants_back_seam_is_a_bridge_and_the_skirt_is_not(ref_female_longskirt):
    """The hot pants' back seam (x = 0 behind the hips, over the cleft) is
    found; the long skirt, loose everywhere already, and the shoes, rigid,
    keep their weights."""
    p = plan(ref_female_longskirt)
    names = [m.name for m in p.items]
    sl = p.item_slices()[names.index("female_casualsuit02")]
    pts = p.ref_points[sl]
    back_seam = (np.abs(pts[:, 0]) < 0.004) & (pts[:, 2] < -0.05) & (pts[:, 1] < 0.0) & (pts[:, 1] > -0.06)
    assert back_seam.sum() >= 4
    assert np.all(p.looseness[sl][back_seam] > 0.5)  # 0-0.13 from their clearance alone
    # the bridges stay bands: most of the hot pants and top stay tight
    assert np.mean(p.looseness[sl] == 0.0) > 0.25
    for name in ("shoes02",):
        s = p.item_slices()[names.index(name)]
        assert np.all(p.looseness[s] == 0.0)
