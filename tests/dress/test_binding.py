"""Binding: exact on the reference, rigid motions, clearance kept on a deformed sphere."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from wearfit_usd.dress.binding import bind
from wearfit_usd.geometry.closest import SurfaceQuery
from wearfit_usd.transforms import matrix_from_quat, quat_normalize


def _sphere(radius, subdiv=4):
    s = trimesh.creation.icosphere(subdivisions=subdiv, radius=radius)
    return np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)


def test_reproduces_reference_items_exactly(ref_male):
    pts = np.concatenate([m.points for m in ref_male.items])
    b = bind(ref_male.body.points, ref_male.body.faces, pts, k=5)
    assert b.matrix.shape == (len(pts), ref_male.body.n_points + 3 * len(ref_male.body.faces))
    assert np.abs(b.evaluate(ref_male.body.points) - pts).max() < 1e-6
    # the documented formulation: one product over [body; v1 + n; v1 + t1; v1 + t2]
    assert np.abs(b.matrix @ b.stacked(ref_male.body.points) - pts).max() < 1e-6
    np.testing.assert_allclose(b.weights.sum(axis=1), 1.0, atol=1e-12)


def test_rigid_body_motion_moves_item_rigidly(ref_male):
    item = ref_male.item("shoes01").points
    body = ref_male.body.points
    b = bind(body, ref_male.body.faces, item, k=5)
    rot = matrix_from_quat(quat_normalize(np.array([0.9, 0.2, -0.3, 0.25])))
    t = np.array([0.3, -1.2, 0.7])
    got = b.evaluate(body @ rot + t)
    np.testing.assert_allclose(got, item @ rot + t, atol=1e-9)


def test_batch_evaluate_equals_single(ref_male):
    item = ref_male.item("fedora01").points
    body = ref_male.body.points
    b = bind(body, ref_male.body.faces, item, k=3)
    frames = np.stack([body, body * 1.1, body + [0, 0.2, 0]])
    batch = b.evaluate(frames)
    for f in range(3):
        np.testing.assert_allclose(batch[f], b.evaluate(frames[f]), atol=1e-12)


def test_sphere_shell_keeps_its_clearance_on_a_deformed_sphere():
    body, faces = _sphere(0.1, 4)
    shell, _ = _sphere(0.108, 3)  # 8 mm off the skin, other tessellation
    b = bind(body, faces, shell, k=5)
    for scale in ([1.5, 1.5, 1.5], [1.3, 0.8, 1.1]):
        target = body * scale
        out = b.evaluate(target)
        d = SurfaceQuery(faces, target).signed_distance(out)
        assert np.abs(d - 0.008).max() < 0.0015, (scale, d.min(), d.max())
        assert abs(np.median(d) - 0.008) < 0.0005


def test_candidate_mask_restricts_triangles():
    body, faces = _sphere(0.1, 3)
    item = body * 1.05
    labels = (body[faces].mean(1)[:, 0] > 0).astype(int)  # two hemispheres
    allowed = np.zeros(len(item), int)  # every vertex: hemisphere 0 only
    b = bind(body, faces, item, k=4, candidate_mask=(labels, allowed))
    assert np.all(labels[b.triangles] == 0)
    assert np.abs(b.evaluate(body) - item).max() < 1e-9


def test_degenerate_triangles_are_not_used():
    body, faces = _sphere(0.1, 2)
    body = np.concatenate([body, [[0.1, 0, 0]]])
    faces = np.concatenate([faces, [[len(body) - 1, len(body) - 1, 0]]])  # zero area
    b = bind(body, faces, body[:10] * 1.02, k=5)
    assert not np.any(b.triangles == len(faces) - 1)
    assert np.isfinite(b.evaluate(body)).all()


def test_bad_arguments():
    body, faces = _sphere(0.1, 1)
    with pytest.raises(ValueError):
        bind(body, faces, np.zeros((0, 3)))
    with pytest.raises(ValueError):
        bind(body, faces, body, k=0)


def _strip(n=4, size=0.1):
    """A flat strip of 2 n triangles along x in the z = 0 plane, normals +z."""
    xs = np.arange(n + 1) * size
    pts = np.concatenate([np.stack([xs, np.zeros_like(xs), np.zeros_like(xs)], 1),
                          np.stack([xs, np.full_like(xs, size), np.zeros_like(xs)], 1)])
    faces = []
    for i in range(n):
        a, b, c, d = i, i + 1, n + 1 + i, n + 2 + i
        faces += [(a, b, d), (a, d, c)]
    return pts, np.array(faces, np.int64)


def test_nearest_by_triangle_distance_not_centroid():
    # one large triangle right under the point, small ones beside it whose
    # centroids are nearer: the large one must be the first bound triangle
    big = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    small = np.array([[0.62, 0.0, 0.0], [0.66, 0.0, 0.0], [0.62, -0.04, 0.0]])
    pts = np.concatenate([big, small])
    faces = np.array([[0, 1, 2], [3, 5, 4]], np.int64)
    q = np.array([[0.6, 0.05, 0.01]])  # over the big triangle, 1 cm above it
    b = bind(pts, faces, q, k=1)
    assert b.triangles[0, 0] == 0
    np.testing.assert_allclose(b.local[0, 0, 2], 0.01, atol=1e-12)


def test_vertex_beyond_a_triangle_is_not_thrown_by_its_stretch():
    # a point 0.5 m beyond the end of a 0.1 m strip, bound to its last
    # triangles: stretching the strip's last column by 2x along x moves the
    # strip's end by 0.1 m and the point should follow it (keep its
    # distance); the affine frame v1 + a e1 + b e2 throws it 0.5 m further
    pts, faces = _strip()
    q = np.array([[0.9, 0.05, 0.02]])
    b = bind(pts, faces, q, k=2)
    moved = pts.copy()
    moved[moved[:, 0] > 0.35, 0] += 0.1
    err = np.linalg.norm(b.evaluate(moved)[0] - [1.0, 0.05, 0.02])
    assert err < 0.1  # the shear of the diagonal triangles turns their frames a little
    v1 = pts[faces[b.triangles[0], 0]]
    e1 = pts[faces[b.triangles[0], 1]] - v1
    e2 = pts[faces[b.triangles[0], 2]] - v1
    ab = np.linalg.lstsq(np.stack([e1[0], e2[0]], 1)[:2], (q[0] - v1[0])[:2], rcond=None)[0]
    mf = moved[faces[b.triangles[0, 0]]]
    affine = mf[0] + ab[0] * (mf[1] - mf[0]) + ab[1] * (mf[2] - mf[0])
    assert err < 0.25 * np.linalg.norm(affine[:2] - [1.0, 0.05])
    # the binding stays exact on its own body and rigid under rotation
    np.testing.assert_allclose(b.evaluate(pts), q, atol=1e-12)
    rot = matrix_from_quat(quat_normalize(np.array([0.8, -0.1, 0.5, 0.3])))
    np.testing.assert_allclose(b.evaluate(pts @ rot), q @ rot, atol=1e-12)


def test_per_vertex_k_pads_with_zero_weights():
    pts, faces = _strip(n=8)
    q = np.array([[0.2, 0.05, 0.01], [0.5, 0.05, 0.01]])
    b = bind(pts, faces, q, k=np.array([2, 6]))
    assert b.triangles.shape == (2, 6)
    assert np.count_nonzero(b.weights[0]) <= 2 and np.count_nonzero(b.weights[1]) > 2
    np.testing.assert_allclose(b.evaluate(pts), q, atol=1e-12)
