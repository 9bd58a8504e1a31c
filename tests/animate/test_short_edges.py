"""Vertices joined by very short item edges kept together (animate.short_edges)."""
from __future__ import annotations

import numpy as np
import pytest

from wearfit_usd.animate.short_edges import WELD_LENGTH, ShortEdgeWeld


def strip():
    """A strip of 4 vertices: 0-1 apart by 0.5 mm, 1-2 by 20 mm, 2-3 by 1 mm."""
    pts = np.array([[0.0, 0.0, 0.0], [0.0005, 0.0, 0.0], [0.0205, 0.0, 0.0], [0.0215, 0.0, 0.0]])
    edges = np.array([[0, 1], [1, 2], [2, 3]])
    return pts, edges


def test_groups_are_the_short_edges():
    pts, edges = strip()
    weld = ShortEdgeWeld(pts, edges)
    assert weld.n_groups == 2
    assert sorted(weld.rows.tolist()) == [0, 1, 2, 3]
    assert weld.group[list(weld.rows).index(0)] == weld.group[list(weld.rows).index(1)]
    assert weld.group[list(weld.rows).index(0)] != weld.group[list(weld.rows).index(2)]


def test_a_group_opens_no_wider_than_at_rest():
    """Known answers: a torn 0.5 mm edge closes to 0.5 mm about its centre,
    along the direction the frame gives it; a group moved rigidly (turned
    and translated) or squeezed is not touched."""
    pts, edges = strip()
    weld = ShortEdgeWeld(pts, edges)
    moved = pts.copy()
    moved[0] += [0.0, 0.004, 0.0]      # the 0.5 mm edge torn open to about 4 mm
    c = 0.5 * (moved[0] + moved[1])
    u = (moved[1] - moved[0]) / np.linalg.norm(moved[1] - moved[0])
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved[2:] = pts[2:] @ rot.T + [0.1, 0.2, 0.3]   # the other group turned 90 degrees and moved
    out = weld(moved.copy())
    np.testing.assert_allclose(out[0], c - 0.00025 * u, atol=1e-12)
    np.testing.assert_allclose(out[1], c + 0.00025 * u, atol=1e-12)
    np.testing.assert_allclose(out[2:], moved[2:], atol=1e-15)
    squeezed = pts.copy()
    squeezed[3] = pts[2] + [0.0002, 0.0, 0.0]
    np.testing.assert_array_equal(weld(squeezed.copy()), squeezed)


def test_chains_and_long_edges_are_left_alone():
    # a chain of 1 mm edges 10 mm long: wider than 2 x WELD_LENGTH from its mean
    x = np.arange(11) * 0.001
    pts = np.stack([x, np.zeros(11), np.zeros(11)], axis=1)
    edges = np.stack([np.arange(10), np.arange(1, 11)], axis=1)
    weld = ShortEdgeWeld(pts, edges)
    assert len(weld) == 0
    moved = pts + np.random.default_rng(0).normal(0, 0.001, pts.shape)
    np.testing.assert_array_equal(weld(moved.copy()), moved)
    # no short edge at all
    weld = ShortEdgeWeld(pts * 10, edges)
    assert len(weld) == 0 and WELD_LENGTH < 0.01


def test_bad_input():
    pts, edges = strip()
    with pytest.raises(ValueError, match="out of range"):
        ShortEdgeWeld(pts, edges + 3)
    with pytest.raises(ValueError, match="length"):
        ShortEdgeWeld(pts, edges, length=0.0)
    with pytest.raises(ValueError, match=r"\(M, 3\)"):
        ShortEdgeWeld(pts[:, :2], edges)
