"""geometry.mesh: topology helpers (known answers)."""
from __future__ import annotations

import numpy as np
import pytest

from wearfit_usd.geometry.mesh import edge_length_percentile, same_topology


def test_same_topology_needs_the_points_and_the_triangles():
    pts = np.zeros((4, 3))
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    assert same_topology(pts, faces, pts + 1.0, faces.copy())          # other positions, one topology
    assert not same_topology(pts, faces, np.zeros((5, 3)), faces)      # an extra point
    assert not same_topology(pts, faces, pts, faces[:1])               # a triangle fewer
    assert not same_topology(pts, faces, pts, faces[:, [0, 2, 1]])     # wound the other way


def test_edge_length_percentile_counts_each_edge_once():
    # a unit square in two triangles: unique edges 1, 1, 1, 1 and the shared diagonal sqrt(2)
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    assert edge_length_percentile(pts, faces, 100) == pytest.approx(np.sqrt(2))
    assert edge_length_percentile(pts, faces, 50) == pytest.approx(1.0)
    # the diagonal counted twice (once per face) would put the 70th percentile at 1.21
    assert edge_length_percentile(pts, faces, 70) < 1.2
