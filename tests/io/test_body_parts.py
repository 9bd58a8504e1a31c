"""A body made of several skinned meshes: found, merged for fitting, written apart."""
from __future__ import annotations

import numpy as np

from wearfit_usd.demo.samples.body import make_body
from wearfit_usd.geometry.body_parts import body_parts
from wearfit_usd.geometry.closest import vertex_normals
from wearfit_usd.io.usd import read_character, triangulate, write_character
from wearfit_usd.model import Mesh, merge_meshes


def _sphere(n=12, m=24, r=1.0, c=(0, 0, 0)):
    th = np.linspace(0.1, np.pi - 0.1, n)
    ph = np.linspace(0, 2 * np.pi, m, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    pts = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(m), indexing="ij")
    a, b = i * m + j, i * m + (j + 1) % m
    f = np.concatenate([np.stack([a, b, b + m], -1).reshape(-1, 3),
                        np.stack([a, b + m, a + m], -1).reshape(-1, 3)])
    return pts * r + np.asarray(c, float), f


def test_body_parts_by_extent_and_layers():
    body = _sphere(r=0.8)                         # the body: 1.6 m across
    dense = _sphere(40, 80, r=0.1, c=(0, 1.0, 0))   # a detailed head: more points, 0.2 m
    shell = _sphere(r=0.83)                       # a garment over the body
    brow = _sphere(8, 12, r=0.105, c=(0, 1.0, 0))  # eyebrows over the head
    joints = np.array([[0, -0.8, 0], [0, 1.1, 0]])
    ch = body_parts([dense, body, shell, brow], joints)
    assert ch.seed == 1                           # by extent, not by point count
    assert ch.parts == [0, 1]
    assert ch.layered == {2: 1, 3: 0}


def _split_body(char, res_parts=("head", "thigh", "upperarm")):
    """The sample body cut into one mesh per region (by dominant joint of
    each quad's first vertex), vertices duplicated along the cuts."""
    b = char.body
    names = char.skeleton.joint_names
    dom = b.joint_indices[np.arange(b.n_points), np.argmax(b.joint_weights, 1)]
    quads = b.face_vertex_indices.reshape(-1, 4)
    label = np.zeros(char.skeleton.n_joints, int)
    for k, key in enumerate(res_parts, start=1):
        for j, n in enumerate(names):
            if key in n.lower():
                sub = np.zeros(len(names), bool)
                sub[j] = True
                for c in range(j + 1, len(names)):
                    if char.skeleton.parents[c] >= 0 and sub[char.skeleton.parents[c]]:
                        sub[c] = True
                label[sub] = k
    ql = label[dom[quads[:, 0]]]
    parts = []
    for k in np.unique(ql):
        q = quads[ql == k]
        used, inv = np.unique(q, return_inverse=True)
        fvi = inv.reshape(-1).astype(np.int64)
        counts = np.full(len(q), 4, np.int64)
        faces, t2p = triangulate(counts, fvi)
        parts.append(Mesh(name=f"part{k}", points=b.points[used], faces=faces,
                          face_vertex_counts=counts, face_vertex_indices=fvi, tri_to_poly=t2p,
                          joint_indices=b.joint_indices[used], joint_weights=b.joint_weights[used]))
    return parts


def test_split_body_is_merged_on_read_and_written_apart(tmp_path):
    char = make_body(resolution=0.03)
    parts = _split_body(char)
    assert len(parts) >= 4
    torso = max(parts, key=lambda m: m.n_points)
    nrm = vertex_normals(torso.points, torso.faces)
    shirt = torso.copy_with_points(torso.points + 0.01 * nrm)
    shirt.name = "shirt"
    char.body = merge_meshes(parts, "Body")
    path = tmp_path / "split.usda"
    write_character(path, char, items=[shirt], skinned_items=True)
    back = read_character(path)
    # every part (and not the skinned shirt over the torso) makes the body
    assert len(back.body.parts) == len(parts)
    assert back.body.n_points == sum(m.n_points for m in parts)
    assert [m.name for m in back.items] == ["shirt"]
    assert np.allclose(np.sort(back.body.points, axis=0), np.sort(char.body.points, axis=0),
                       atol=1e-5)
    # written apart again: one skinned Mesh per part under Body
    out = tmp_path / "again.usda"
    write_character(out, back, items=[])
    from pxr import Usd, UsdGeom
    st = Usd.Stage.Open(str(out))
    kids = [p for p in st.GetPrimAtPath("/Root/Character/Body").GetChildren() if p.IsA(UsdGeom.Mesh)]
    assert len(kids) == len(parts)
    again = read_character(out)
    assert again.body.n_points == back.body.n_points and not again.items
