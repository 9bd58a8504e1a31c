"""Batched rigid parts: exact on a known similarity, equal to one Umeyama fit per group."""
import numpy as np

from wearfit_usd.dress.rigid_parts import RigidParts
from wearfit_usd.geometry.mesh import similarity_fit
from wearfit_usd.transforms import axis_rotation


def _groups(rng, n_body=300, n_items=200):
    body = rng.normal(size=(n_body, 3))
    items = rng.normal(size=(n_items, 3))
    groups = []
    for gv in np.array_split(rng.permutation(n_items)[:150], 3):
        bv = rng.choice(n_body, 40, replace=False)
        groups.append((gv, bv, rng.uniform(0.1, 1.0, size=40)))
    return body, items, groups


def test_known_similarity_is_recovered_exactly():
    rng = np.random.default_rng(0)
    body, items, groups = _groups(rng)
    rot = axis_rotation(0, 0.7) @ axis_rotation(1, -1.1) @ axis_rotation(2, 0.4)
    new_body = 1.3 * body @ rot + [0.1, -2.0, 0.5]
    out = RigidParts(groups, body, items)(new_body, items.copy())
    moved = np.concatenate([gv for gv, _, _ in groups])
    np.testing.assert_allclose(out[moved], (1.3 * items @ rot + [0.1, -2.0, 0.5])[moved], atol=1e-12)
    untouched = np.setdiff1d(np.arange(len(items)), moved)
    np.testing.assert_array_equal(out[untouched], items[untouched])
    s, r, _ = RigidParts(groups, body, items, scale=False).transforms(new_body)
    np.testing.assert_allclose(s, 1.0)
    np.testing.assert_allclose(r, np.broadcast_to(rot, r.shape), atol=1e-12)


def test_matches_a_weighted_umeyama_fit_per_group_under_noise():
    rng = np.random.default_rng(1)
    body, items, groups = _groups(rng)
    new_body = body * [1.2, 0.9, 1.0] + rng.normal(scale=0.05, size=body.shape)  # not a similarity
    s, rot, t = RigidParts(groups, body, items).transforms(new_body)
    for g, (_, bv, bw) in enumerate(groups):
        sc, r, tr = similarity_fit(body[bv], new_body[bv], bw)  # one Umeyama fit, the reference
        np.testing.assert_allclose(rot[g], r, atol=1e-10)
        np.testing.assert_allclose(s[g], sc, rtol=1e-10)
        np.testing.assert_allclose(t[g], tr, atol=1e-10)
        assert np.linalg.det(rot[g]) > 0
