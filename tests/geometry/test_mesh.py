"""geometry.mesh: topology helpers (known answers)."""
from __future__ import annotations

import numpy as np
import pytest

from wearfit_usd.geometry.mesh import adjacency, edge_length_percentile, same_topology, short_edge_weights


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


def test_short_edge_weights_known_answers():
    # a unit square split into two triangles, and a vertex 1 mm from corner 0
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.001, 0, 0]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 4, 3]])
    nb = adjacency(faces, len(pts))
    w = short_edge_weights(nb, pts)
    assert (w != w.T).nnz == 0
    # the square's edges weigh 1 (none under half its vertices' mean edge)
    for i, j in [(0, 1), (1, 2), (2, 3), (0, 3), (0, 2)]:
        assert w[i, j] == 1.0
    # 0-4: 1 mm; vertex 4's edges: 1 mm and 1 m (mean 0.5005), vertex 0's: 1, 1, sqrt 2, 0.001
    h0 = (1 + 1 + np.sqrt(2) + 0.001) / 4
    h4 = (0.001 + np.sqrt(1.0 + 0.001 ** 2)) / 2
    np.testing.assert_allclose(w[0, 4], (0.5 * min(h0, h4) / 0.001) ** 2)
