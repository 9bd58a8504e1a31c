"""geometry.mesh: topology helpers (known answers)."""
from __future__ import annotations

import numpy as np

from wearfit_usd.geometry.mesh import same_topology


def test_same_topology_needs_the_points_and_the_triangles():
    pts = np.zeros((4, 3))
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    assert same_topology(pts, faces, pts + 1.0, faces.copy())          # other positions, one topology
    assert not same_topology(pts, faces, np.zeros((5, 3)), faces)      # an extra point
    assert not same_topology(pts, faces, pts, faces[:1])               # a triangle fewer
    assert not same_topology(pts, faces, pts, faces[:, [0, 2, 1]])     # wound the other way
