"""A skirt's hem against the legs' outline at its height (animate.hem_span)."""
from __future__ import annotations

import numpy as np
import pytest

from wearfit_usd.animate.hem_span import HemSpan, narrow_frames, outline
from wearfit_usd.geometry.mesh import boundary_loops


def tube(radius, y0, y1, n=48, rows=6, centre=(0.0, 0.0)):
    """An open tube round the y axis: (points, faces), rows of n vertices."""
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    ys = np.linspace(y1, y0, rows)   # top row first
    pts = np.array([[centre[0] + radius * np.cos(t), y, centre[1] + radius * np.sin(t)] for y in ys for t in a])
    faces = []
    for r in range(rows - 1):
        for i in range(n):
            p, q = r * n + i, r * n + (i + 1) % n
            faces += [[p, q, p + n], [q, q + n, p + n]]
    return pts, np.array(faces, dtype=np.int64)


def body(spread):
    """Two leg tubes (radius 6 cm, 0-80 cm high) ``spread`` apart in x, a
    torso tube (radius 15 cm) from 80 cm up: points and leg / torso masks."""
    legs = [tube(0.06, 0.0, 0.8, rows=41, centre=(s * spread / 2, 0.0))[0] for s in (-1, 1)]
    torso = tube(0.15, 0.8, 1.4, rows=13)[0]
    pts = np.concatenate(legs + [torso])
    n_leg = sum(len(x) for x in legs)
    return pts, np.arange(len(pts)) < n_leg, np.arange(len(pts)) >= n_leg


def test_boundary_loops_of_an_open_tube_are_its_two_rims_in_order():
    pts, faces = tube(0.2, 0.0, 0.5, n=12, rows=4)
    loops = boundary_loops(faces)
    assert len(loops) == 2
    heights = sorted(float(pts[lp, 1].mean()) for lp in loops)
    assert heights == pytest.approx([0.0, 0.5])
    for lp in loops:
        assert len(lp) == 12 and len(set(lp.tolist())) == 12
        # consecutive vertices are neighbours on the rim (one step of 30 degrees)
        ring = pts[lp]
        steps = np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1)
        np.testing.assert_allclose(steps, 2 * 0.2 * np.sin(np.pi / 12), rtol=1e-9)
    # a closed mesh has none
    closed = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    assert boundary_loops(closed) == []


def test_outline_is_the_convex_hull_perimeter():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.5]])
    assert outline(square) == pytest.approx(4.0)
    assert outline(square[:2]) == 0.0
    assert outline(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])) == 0.0   # on a line


@pytest.mark.parametrize("spread, narrow", [(0.14, False), (0.5, True)])
def test_legs_apart_are_wider_than_a_straight_skirt_s_hem(spread, narrow):
    """A straight skirt (radius 16 cm: hem 1.0 m) hanging from the torso to
    20 cm over the floor; legs 14 cm apart fit in it, 50 cm apart do not:
    the legs' outline is 2 pi r + 2 d (0.66 and 1.38 m)."""
    skirt, faces = tube(0.16, 0.2, 0.95, n=64, rows=10)
    b0, legs, torso = body(0.14)
    span = HemSpan(skirt, faces, b0, legs, torso)
    assert span.hem == pytest.approx(2 * np.pi * 0.16, rel=0.01)
    assert span.height0 == pytest.approx(0.2, abs=1e-9)
    b, _, _ = body(spread)
    expect = 2 * np.pi * 0.06 + 2 * spread
    got = span(b)
    assert got == pytest.approx(expect, rel=0.01)
    assert (len(narrow_frames(np.array([got]), span.hem)) == 1) == narrow
    # the hem hangs from the crotch: the body lowered 10 cm, the slice too
    low = b.copy()
    low[:, 1] -= 0.1
    assert span.height(low) == pytest.approx(span.height(b) - 0.1)


def test_a_skirt_without_a_hem_or_a_body_without_legs_is_refused():
    b0, legs, torso = body(0.14)
    closed = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    with pytest.raises(ValueError, match="no hem"):
        HemSpan(b0[:4], closed, b0, legs, torso)
    skirt, faces = tube(0.16, 0.2, 0.95)
    with pytest.raises(ValueError, match="leg and torso"):
        HemSpan(skirt, faces, b0, np.zeros(len(b0), dtype=bool), torso)
