"""dress.hidden_body: covered body polygons (known answers on a box) and
polygons dropped with their data re-indexed."""
from __future__ import annotations

import numpy as np

from wearfit_usd.dress.hidden_body import coverage, drop_polygons, hidden_polygons, hide_or_drop
from wearfit_usd.geometry.closest import VertexNormals
from wearfit_usd.io.usd import triangulate
from wearfit_usd.model import Mesh, Primvar

# the box of tests/tiny_stage.py: 0.4 x 2 x 0.2 m, polygon 0 faces +z
POINTS = np.array([(-0.2, 0, 0.1), (0.2, 0, 0.1), (-0.2, 2, 0.1), (0.2, 2, 0.1), (-0.2, 0, -0.1),
                   (0.2, 0, -0.1), (-0.2, 2, -0.1), (0.2, 2, -0.1)], dtype=float)
COUNTS = np.full(6, 4)
INDICES = np.array([0, 1, 3, 2, 2, 3, 7, 6, 6, 7, 5, 4, 4, 5, 1, 0, 2, 6, 4, 0, 7, 3, 1, 5])


def _box() -> Mesh:
    faces, t2p = triangulate(COUNTS, INDICES)
    st = Primvar("st", "texCoord2f[]", "faceVarying", np.arange(48, dtype=np.float32).reshape(24, 2))
    uv2 = Primvar("uv2", "texCoord2f[]", "vertex", np.zeros((2, 2), np.float32),
                  indices=np.array([0, 1, 0, 1, 0, 1, 0, 1]))
    wear = Primvar("wear", "float[]", "uniform", np.arange(6, dtype=np.float32))
    return Mesh("Body", POINTS.copy(), faces, COUNTS, INDICES, t2p, primvars=[st, uv2, wear],
                joint_indices=np.arange(8)[:, None], joint_weights=np.ones((8, 1)))


def _plate(z=0.12):
    pts = np.array([(-1, -1, z), (1, -1, z), (1, 3, z), (-1, 3, z)], dtype=float)
    return ("plate", pts, np.array([[0, 1, 2], [0, 2, 3]]))


def test_plate_in_front_hides_the_front_face_only():
    box = _box()
    cov = coverage(POINTS, box.faces, COUNTS, INDICES, [_plate()])
    assert cov.vertex[0].tolist() == [True] * 4 + [False] * 4
    n = VertexNormals(box.faces, 8)(POINTS)
    np.testing.assert_allclose(cov.gap[0, :4], 0.02 / n[:4, 2], atol=1e-9)  # along the normal to the plate's plane
    assert np.isinf(cov.gap[0, 4:]).all()
    h = hidden_polygons(cov, COUNTS, INDICES)
    assert h["hidden_under_items"].tolist() == [0] and h["hidden_under_plate"].tolist() == [0]
    # shots: the front corners are 0.2 m (one box edge) from the uncovered back ones
    assert hidden_polygons(cov, COUNTS, INDICES, POINTS, box.faces, depth=0.1)["hidden_under_items"].tolist() == [0]
    assert hidden_polygons(cov, COUNTS, INDICES, POINTS, box.faces, depth=0.3)["hidden_under_items"].tolist() == []
    # an item beyond the ray's reach covers nothing
    far = hidden_polygons(coverage(POINTS, box.faces, COUNTS, INDICES, [_plate(0.3)]), COUNTS, INDICES)
    assert far["hidden_under_items"].tolist() == [] and "hidden_under_plate" not in far


def test_drop_polygons_reindexes_points_weights_and_primvars():
    box = _box()
    out, keep = drop_polygons(box, np.array([0, 2]))  # the front and back faces
    assert keep.tolist() == [False, True, False, True, True, True]
    assert out.n_points == 8  # every vertex is still used by a side face
    out, keep = drop_polygons(box, np.array([0, 1, 2]))  # front, top, back: sides keep all 8
    assert len(out.face_vertex_counts) == 3 and out.n_points == 8
    out, keep = drop_polygons(box, np.array([0, 1, 2, 4, 5]))  # only the bottom (4, 5, 1, 0) is left
    assert out.n_points == 4 and out.face_vertex_indices.tolist() == [2, 3, 1, 0]
    np.testing.assert_array_equal(out.points, POINTS[[0, 1, 4, 5]])
    assert out.joint_indices[:, 0].tolist() == [0, 1, 4, 5]
    assert len(out.faces) == 2 and out.faces.max() == 3 and out.tri_to_poly.tolist() == [0, 0]
    st, uv2, wear = out.primvars
    np.testing.assert_array_equal(st.values, np.arange(48, dtype=np.float32).reshape(24, 2)[12:16])
    assert uv2.indices.tolist() == [0, 1, 0, 1] and wear.values.tolist() == [3.0]


def test_hide_or_drop():
    box = _box()
    body, subsets, keep = hide_or_drop(box, POINTS, [_plate()])
    assert body is box and keep is None and subsets["hidden_under_items"].tolist() == [0]
    body, subsets, keep = hide_or_drop(box, POINTS, [_plate()], delete=True)
    assert subsets == {} and keep.tolist() == [False] + [True] * 5 and len(body.face_vertex_counts) == 5
