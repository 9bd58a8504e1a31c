"""dress.item_weights: skin weights of dressed items from their K-triangle
binding; `wearfit dress --items` and unrigged targets (--rig-from-reference)."""
from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import BVH_DIR, USD_DIR
from wearfit_usd.dress.binding import bind
from wearfit_usd.dress.item_weights import (
    HINGE_BAND,
    MAX_INFLUENCES,
    articulated_pieces,
    articulated_weights,
    binding_coefficients,
    hinge_band,
    item_skin_weights,
    piece_joints,
    prune,
    rigid_group_weights,
    weight_matrix,
)
from wearfit_usd.geometry.mesh import edges as mesh_edges
from wearfit_usd.geometry.mesh import similarity_fit

# a unit square of two triangles; each corner on one joint of four
SQUARE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
SQUARE_FACES = np.array([[0, 1, 2], [0, 2, 3]])
CORNER_JOINT = np.array([[0], [1], [2], [3]])
ONE = np.ones((4, 1))


def test_a_bound_vertex_takes_the_barycentric_blend_of_its_triangles_corners():
    # 2 mm above the point 0.5 v0 + 0.2 v1 + 0.3 v2 of the first triangle
    p = 0.5 * SQUARE[0] + 0.2 * SQUARE[1] + 0.3 * SQUARE[2] + [0.0, 0.0, 0.002]
    b = bind(SQUARE, SQUARE_FACES, p[None], k=1)
    ji, jw = item_skin_weights(b, CORNER_JOINT, ONE, 4)
    dense = np.zeros(4)
    dense[ji[0]] = jw[0]
    np.testing.assert_allclose(dense, [0.5, 0.2, 0.3, 0.0], atol=1e-9)


def _crease():
    """An arm and a torso meeting at a crease: triangle 0 (on joint 0, the
    arm) in the plane z = 0 from the crease x = 0 out, triangle 1 (joint
    1, the torso) rising at 60 degrees from 1 mm across it; and an item
    vertex 2 mm over the arm, 3 mm from the crease, bound to both (k=2)."""
    c, s_ = np.cos(np.pi / 3), np.sin(np.pi / 3)
    body = np.array([[0.0, -0.05, 0.0], [0.1, 0.0, 0.0], [0.0, 0.05, 0.0],
                     [-0.001, -0.05, 0.0], [-0.001 - 0.1 * c, 0.0, 0.1 * s_], [-0.001, 0.05, 0.0]])
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    joints = np.array([[0], [0], [0], [1], [1], [1]])
    return body, faces, joints, np.array([[0.003, 0.0, 0.002]])


def test_the_nearest_triangles_weigh_most_so_the_skin_across_a_crease_counts_little():
    """Known answer: bound to the arm's triangle (binding weight w0) and the
    torso's (w1), the vertex takes the torso's joint in the share
    w1^2 / (w0^2 + w1^2) (BLEND_POWER 2), not w1 (the plain blend). Posed
    with the arm turned 40 degrees about its far corner, it stays closer to
    its 2 mm over the arm than with the plain blend, which puts it under
    the arm's surface."""
    body, faces, joints, p = _crease()
    b = bind(body, faces, p, k=2)
    w0, w1 = b.weights[0]
    assert w1 > 0.15                        # the torso's triangle is in its binding
    ji, jw = item_skin_weights(b, joints, np.ones((6, 1)), 2)
    dense = np.zeros(2)
    dense[ji[0]] = jw[0]
    np.testing.assert_allclose(dense, [w0 ** 2, w1 ** 2] / (w0 ** 2 + w1 ** 2), atol=1e-12)
    plain = (binding_coefficients(b, 6) @ weight_matrix(joints, np.ones((6, 1)), 2)).toarray()[0]
    np.testing.assert_allclose(plain, [w0, w1], atol=1e-12)
    mats = np.stack([_rot([0, 1, 0], 0.7, np.array([0.1, 0.0, 0.0])), np.eye(4)])
    arm = _skin(body[:3], np.array([[1.0, 0.0]] * 3), mats)
    normal = np.cross(arm[1] - arm[0], arm[2] - arm[0])
    normal /= np.linalg.norm(normal)

    def over_arm(w):
        return float((_skin(p, w[None], mats)[0] - arm[0]) @ normal)
    assert over_arm(plain) < -0.008          # 8.5 mm under the arm's surface
    assert over_arm(dense) > -0.001          # at most 1 mm under it
    with pytest.raises(ValueError, match="power"):
        binding_coefficients(b, 6, power=0.0)


def test_weights_sum_to_one_with_at_most_eight_influences_strongest_first():
    rng = np.random.default_rng(3)
    w = rng.random((50, 20))
    ji, jw = prune(w)
    assert ji.shape == (50, MAX_INFLUENCES)
    np.testing.assert_allclose(jw.sum(axis=1), 1.0)
    assert (np.diff(jw, axis=1) <= 1e-12).all()
    # the kept joints are the row's 8 largest
    top = np.sort(np.argsort(-w, axis=1)[:, :8], axis=1)
    assert (np.sort(ji, axis=1) == top).all()


def test_a_rigid_group_over_one_joint_moves_with_that_joint_alone():
    pts = np.array([[0.2, 0.1, 0.01], [0.8, 0.3, 0.01], [0.3, 0.8, 0.01]])
    b = bind(SQUARE, SQUARE_FACES, pts, k=2)
    # body patch: corners 0 and 1, 95 % of its weight on joint 0's corner
    group = (np.arange(3), np.array([0, 1]), np.array([0.95, 0.05]))
    ji, jw = item_skin_weights(b, CORNER_JOINT, ONE, 4, rigid_groups=[group])
    assert (ji[:, 0] == 0).all() and np.allclose(jw[:, 0], 1.0)
    # a patch shared by two joints: each vertex keeps the skin under it
    shared = (np.arange(3), np.array([0, 1]), np.array([0.5, 0.5]))
    ji2, jw2 = item_skin_weights(b, CORNER_JOINT, ONE, 4, rigid_groups=[shared])
    free, free_w = item_skin_weights(b, CORNER_JOINT, ONE, 4)
    assert (ji2 == free).all() and np.allclose(jw2, free_w)


# a leg: 0 root, 1 thigh, 2 calf, 3 foot, 4 ball (toes), 5 a toe's second
# segment, 6 the other leg
LEG_PARENTS = np.array([-1, 0, 1, 2, 3, 4, 0])


def test_the_pieces_of_a_part_on_the_foot_are_calf_foot_and_toes():
    # the toe's second segment moves with the toe cap; everything outside
    # the foot's subtree (thigh, root, the other leg) with the collar's calf
    assert piece_joints(LEG_PARENTS, 3).tolist() == [2, 2, 2, 3, 4, 4, 2]
    # a root-carried part has no parent piece
    assert piece_joints(LEG_PARENTS, 0).tolist() == [0, 1, 1, 1, 1, 1, 6]


def test_articulated_weights_snap_the_skin_to_pieces_with_linear_hinges():
    w = np.zeros((5, 7))
    w[0, [3, 4]] = [0.95, 0.05]          # sole: wholly the foot
    w[1, [3, 4, 5]] = [0.05, 0.5, 0.45]  # toe cap: the toe segments summed, wholly the ball
    w[2, [3, 4]] = [0.5, 0.5]            # mid hinge
    w[3, [2, 3]] = [0.6, 0.4]            # collar: on the calf
    w[4, [1, 3]] = [0.3, 0.7]            # thigh weight counts in the calf's piece, and stays the thigh's
    out = articulated_weights(w, LEG_PARENTS, hinge=(0.1, 0.9))
    expect = np.zeros((5, 7))
    expect[0, 3] = 1.0
    expect[1, 4] = 1.0
    expect[2, [3, 4]] = [0.5, 0.5]
    expect[3, [2, 3]] = [0.625, 0.375]
    expect[4, [1, 3]] = [0.25, 0.75]
    np.testing.assert_allclose(out, expect, atol=1e-12)
    assert [p.tolist() for p in articulated_pieces(np.tile(out, (3, 1)))] == [[0, 5, 10], [1, 6, 11]]
    # the parent piece's share is spread over its joints as the skin spreads it
    two = articulated_weights(np.array([[0.0, 0.3, 0.3, 0.4, 0.0, 0.0, 0.0]]), LEG_PARENTS, hinge=(0.1, 0.9))
    np.testing.assert_allclose(two, [[0.0, 0.3125, 0.3125, 0.375, 0.0, 0.0, 0.0]], atol=1e-12)
    with pytest.raises(ValueError, match="hinge"):
        articulated_weights(w, LEG_PARENTS, hinge=(0.9, 0.1))


def test_with_parents_a_part_on_one_joint_is_articulated_too():
    """Short hair: its body patch is 95 % on the head (3 here), so without
    the skeleton it went wholly on the head and the neck (2) came through
    its nape in motion; with the parents the nape vertex takes its hinge
    share of the neck, the rest stays on the head alone."""
    import scipy.sparse as sps
    dense = np.zeros((3, 7))
    dense[0, 3] = 1.0
    dense[1, [2, 3]] = [0.3, 0.7]     # the nape, partly on the neck
    dense[2, [3, 4]] = [0.97, 0.03]
    body_w = sps.csr_matrix(np.eye(7)[[3, 3]])
    group = (np.arange(3), np.array([0, 1]), np.array([0.95, 0.05]))
    on_one = rigid_group_weights(dense, group, body_w)
    assert (on_one[:, 3] == 1.0).all()
    art = rigid_group_weights(dense, group, body_w, LEG_PARENTS)
    expect = np.zeros((3, 7))
    expect[[0, 2], 3] = 1.0
    expect[1, [2, 3]] = [0.25, 0.75]
    np.testing.assert_allclose(art, expect, atol=1e-12)


# a neck of two joints under the head: 0 root, 1 spine, 2 neck, 3 neck1, 4 head
NECK_PARENTS = np.array([-1, 0, 1, 2, 3])


def test_a_nape_wholly_on_the_neck_piece_follows_the_skin_under_it_on_a_two_joint_neck():
    """Short hair on a CMU-style neck (Neck, Neck1, Head): the nape's skin
    is 0.6 Neck and 0.4 Neck1. The nape vertex, wholly in the head's
    parent piece, takes those proportions and is posed exactly where the
    skin under it goes when the neck bends; on Neck1 alone (the parent
    joint only, as before) it was centimetres off."""
    skin = np.zeros((2, 5))
    skin[0, 4] = 1.0                  # the crown, on the head
    skin[1, [2, 3]] = [0.6, 0.4]      # the nape
    art = articulated_weights(skin, NECK_PARENTS, hinge=(0.1, 0.9))
    np.testing.assert_allclose(art, skin, atol=1e-12)
    pts = np.array([[0.0, 0.0, 0.20], [0.0, -0.06, 0.05]])
    mats = np.tile(np.eye(4), (5, 1, 1))
    mats[2] = _rot([1, 0, 0], 0.5, np.zeros(3))      # the neck bends forward at its base
    mats[3] = mats[2] @ _rot([1, 0, 0], 0.3, np.array([0.0, 0.0, 0.06]))
    mats[4] = mats[3]
    np.testing.assert_allclose(_skin(pts, art, mats), _skin(pts, skin, mats), atol=1e-12)
    on_parent = np.zeros((2, 5))
    on_parent[0, 4] = on_parent[1, 3] = 1.0
    assert np.linalg.norm(_skin(pts, on_parent, mats)[1] - _skin(pts, skin, mats)[1]) > 0.01


def _skin(points, weights, mats):
    """LBS of (P, 3) points by (J, 4, 4) world-from-bind matrices (column vectors)."""
    hom = np.c_[points, np.ones(len(points))]
    per_joint = np.einsum("jab,pb->pja", mats, hom)[..., :3]
    return np.einsum("pj,pja->pa", weights, per_joint)


def _rot(axis, angle, centre):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    r = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = centre - r @ centre
    return m


def test_an_articulated_shoe_moves_its_pieces_rigidly_where_the_skin_weights_do_not():
    """A synthetic shoe along x over calf (ankle at x=0), foot and toes
    (toe joint at x=0.15), with the skin's wide linear blends: posed with
    the ankle and the toes bent, each articulated piece stays within 1e-9 m
    of a rigid transform, while the same pieces skinned with the skin's
    weights are millimetres off."""
    rng = np.random.default_rng(7)
    pts = np.c_[rng.uniform(-0.05, 0.22, 400), rng.uniform(-0.04, 0.04, 400), rng.uniform(0.0, 0.12, 400)]
    x, z = pts[:, 0], pts[:, 2]
    calf = np.clip((z - 0.04) / 0.08, 0, 1) * np.clip(1 - x / 0.1, 0, 1)
    toe = np.clip((x - 0.11) / 0.08, 0, 1) * (1 - calf)
    skin = np.zeros((400, 7))
    skin[:, 2], skin[:, 4] = calf, toe
    skin[:, 3] = 1 - calf - toe
    art = articulated_weights(skin, LEG_PARENTS)
    # world-from-bind: the calf tilts about the ankle, the foot stays, the toes bend up
    mats = np.tile(np.eye(4), (7, 1, 1))
    mats[[0, 1, 2, 6]] = _rot([0, 1, 0], 0.35, np.zeros(3))
    mats[[4, 5]] = _rot([0, 1, 0], -0.5, np.array([0.15, 0.0, 0.0]))
    pieces = articulated_pieces(art)
    assert len(pieces) == 3 and sum(map(len, pieces)) >= 0.4 * len(pts)
    for weights, bound in ((art, 1e-9), (skin, None)):
        posed = _skin(pts, weights, mats)
        err = []
        for p in pieces:
            s, r, t = similarity_fit(pts[p], posed[p])
            err.append(np.linalg.norm(s * pts[p] @ r + t - posed[p], axis=1).max())
        if bound is not None:
            assert max(err) < bound, err
        else:
            assert max(err) > 0.003, err


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "wearfit_usd", *map(str, args)], capture_output=True, text=True)


def _tri(mesh):
    from pxr import UsdGeom  # noqa: F401
    cnt = np.array(mesh.GetFaceVertexCountsAttr().Get())
    idx = np.array(mesh.GetFaceVertexIndicesAttr().Get())
    start = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    out = [np.stack([idx[start[m]], idx[start[m] + j], idx[start[m] + j + 1]], 1)
           for j in range(1, cnt.max() - 1) for m in [cnt > j + 1]]
    return np.concatenate(out)


@pytest.mark.slow
def test_usdskel_skinned_items_follow_the_posed_body_like_the_per_frame_redress(tmp_path):
    """The skinned copies of `dress --items both`, posed by UsdSkel itself with
    a walk's joint transforms, have new penetrations within 1 percentage
    point of the per-frame redress (`animate`) on the same frames (issue
    19). Their rest points are fitted to example poses (animate.skin_fit);
    with `--no-skin-fit` the tight suit is over it (LBS of the skin's
    weights has no push-out at the pinched armpits: 1.87 % against 0.41 %
    on the frames measured here; 1.05 % with the fit)."""
    from pxr import Usd, UsdGeom, UsdSkel

    from tests.usdskel_reference import author_animation, usdskel_skinned_points
    from wearfit_usd.geometry.closest import SurfaceQuery
    ref, tgt = USD_DIR / "ref_female.usda", USD_DIR / "body_female_thin.usdc"
    shot = tmp_path / "shot.usdc"
    r = _cli("animate", ref, tgt, BVH_DIR / "cmu_07_01_walk.bvh", "-o", shot, "--end", "60", "-q")
    assert r.returncode == 0, r.stderr
    s_shot = Usd.Stage.Open(str(shot))
    frames = list(range(0, int(s_shot.GetEndTimeCode()) + 1, 2))
    assert len(frames) >= 7
    cache = UsdSkel.Cache()
    root = next(p for p in s_shot.Traverse() if p.IsA(UsdSkel.Root))
    cache.Populate(UsdSkel.Root(root), Usd.PrimDefaultPredicate)
    sq = cache.GetSkelQuery(UsdSkel.Skeleton(next(p for p in s_shot.Traverse() if p.IsA(UsdSkel.Skeleton))))
    local = np.array([np.array(sq.ComputeJointLocalTransforms(f)) for f in frames])
    gaps = {}
    for flags in ((), ("--no-skin-fit",)):
        dressed = tmp_path / f"dressed{len(flags)}.usda"  # a new layer each (USD keeps opened ones)
        r = _cli("dress", ref, tgt, "-o", dressed, "-q", *flags)
        assert r.returncode == 0, r.stderr
        st = Usd.Stage.Open(str(dressed))
        skel = next(p for p in st.Traverse() if p.IsA(UsdSkel.Skeleton))
        author_animation(st, str(skel.GetPath()), local, list(sq.GetJointOrder()))
        body_path = "/Root/Character/Body"
        faces = _tri(UsdGeom.Mesh(st.GetPrimAtPath(body_path)))
        q0 = SurfaceQuery(faces, np.array(UsdGeom.Mesh(st.GetPrimAtPath(body_path)).GetPointsAttr().Get(), float))
        skinned = [p for p in st.Traverse() if p.IsA(UsdGeom.Mesh) and p.GetName().endswith("_skinned")]
        assert len(skinned) == 4
        bodies = [SurfaceQuery(faces, usdskel_skinned_points(st, body_path, k)) for k in range(len(frames))]
        for prim in skinned:
            name = prim.GetName()[:-len("_skinned")]
            # "new": outside the body in the static dress (the point copy
            # written beside it; the fitted copy's rest points stand further out)
            static = np.array(UsdGeom.Mesh(st.GetPrimAtPath(f"/Root/Items/{name}")).GetPointsAttr().Get(), float)
            outside = q0.closest(static)["distance"] > 0
            item = UsdGeom.Mesh(s_shot.GetPrimAtPath(f"/Root/Items/{name}"))
            sk = max(100 * np.mean((q.closest(usdskel_skinned_points(st, str(prim.GetPath()), k))["distance"] < 0)
                                   & outside) for k, q in enumerate(bodies))
            rd = max(100 * np.mean((q.closest(np.array(item.GetPointsAttr().Get(f), float))["distance"] < 0)
                                   & outside) for f, q in zip(frames, bodies))
            gaps[(flags, name)] = sk - rd
            if flags:
                continue
            assert sk <= rd + 1.0, (name, sk, rd)
    # the fit does the work: without it the tight suit is over (1.87 % against 0.41 %)
    assert gaps[(("--no-skin-fit",), "female_casualsuit01")] > 1.0


@pytest.mark.slow
def test_a_scan_without_skeleton_is_rigged_and_dressed_in_one_command(tmp_path):
    """A remeshed dev body with its skeleton stripped, as .obj: one `dress`
    fits the reference onto it, carries the rig over, says so, and dresses
    it; the fit covers the scan both ways (p99 <= 5 mm) and the items have no
    new penetrations measured against the scan itself."""
    import trimesh

    from wearfit_usd.io.usd import read_character
    src = read_character(USD_DIR / "body_female_heavy_remeshed.usdc")
    scan = tmp_path / "scan.obj"
    trimesh.Trimesh(src.body.points * 100.0, src.body.faces, process=False).export(scan)  # centimetres
    out, rep = tmp_path / "dressed.usda", tmp_path / "rep.json"
    r = _cli("dress", USD_DIR / "ref_female.usda", scan, "-o", out, "--report", rep)
    assert r.returncode == 0, r.stderr
    log = r.stdout + r.stderr
    assert "0.01 m per unit" in log and "rigging it from" in log
    m = re.search(r"fitted->target p99 ([\d.]+) mm, target->fitted p99 ([\d.]+) mm", log)
    assert m and float(m.group(1)) <= 5.0 and float(m.group(2)) <= 5.0, log
    rows = json.loads(rep.read_text())["items"]
    assert max(r["new_pen_pct"] for r in rows) <= 0.1, rows
    dressed = read_character(out)
    assert dressed.skeleton is not None and dressed.skeleton.n_joints == read_character(
        USD_DIR / "ref_female.usda").skeleton.n_joints
    assert sorted(m.name for m in dressed.items) == sorted(r["item"] for r in rows)
    # animated by one command too, items measured against the scan
    shot = tmp_path / "walk.usdc"
    r = _cli("animate", USD_DIR / "ref_female.usda", scan, BVH_DIR / "cmu_07_01_walk.bvh", "-o", shot,
             "--end", "30", "-q")
    assert r.returncode == 0, r.stderr
    from pxr import Usd, UsdGeom
    st = Usd.Stage.Open(str(shot))
    suit = UsdGeom.Mesh(st.GetPrimAtPath("/Root/Items/female_casualsuit01")).GetPointsAttr()
    assert len(suit.GetTimeSamples()) >= 7
    # without a skeleton and with --no-rig-from-reference: a clear refusal
    r = _cli("dress", USD_DIR / "ref_female.usda", scan, "-o", tmp_path / "x.usda", "--no-rig-from-reference")
    assert r.returncode != 0 and "no skeleton" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "x.usda").exists()


def test_regions_of_a_rig_carried_onto_a_scan_are_those_of_the_reference():
    """A fit leaves the carried skeleton's root a fraction of a millimetre off
    the midline: it must not count as one side's lowest joint (that made the
    whole scan one leg, and animating it failed in the binding)."""
    from wearfit_usd.dress.regions import joint_regions
    from wearfit_usd.fit.rig import fitted_skeleton
    from wearfit_usd.io.usd import read_character
    skel = read_character(USD_DIR / "ref_female.usda").skeleton
    moved = np.array(skel.bind_world, dtype=np.float64).copy()
    moved[:, 3, 0] += 0.0003
    carried = fitted_skeleton(skel, moved)
    want = joint_regions(skel)
    assert len(set(want.tolist())) == 6
    assert (joint_regions(carried) == want).all()


def test_a_hinge_band_spreads_a_step_in_a_pieces_share_linearly_over_its_width():
    """A strip of 12 vertices 5 mm apart whose share steps from 0 to 1
    between x = -2.5 and +2.5 mm: spread over 30 mm the share is
    clip(1/2 + x / 0.03, 0, 1); a separate piece the line does not cross
    keeps its shares; a share already rising over the band is kept; the
    ends of a crossed edge longer than the band stay in the band."""
    x = np.arange(-27.5, 30.0, 5.0) / 1000.0
    share = np.r_[(x > 0).astype(float), 0.2, 0.3]
    edges = np.r_[np.c_[np.arange(11), np.arange(1, 12)], [[12, 13]]]
    lengths = np.r_[np.full(11, 0.005), 0.01]
    out = hinge_band(share, edges, lengths, width=0.03)
    np.testing.assert_allclose(out[:12], np.clip(0.5 + x / 0.03, 0.0, 1.0), atol=1e-12)
    np.testing.assert_array_equal(out[12:], [0.2, 0.3])
    # a share already between the pieces: the crossing where it is 1/2
    out = hinge_band(np.array([0.0, 0.25, 0.75, 1.0]), np.c_[[0, 1, 2], [1, 2, 3]], np.full(3, 0.01), width=0.02)
    np.testing.assert_allclose(out, [0.0, 0.25, 0.75, 1.0], atol=1e-12)
    np.testing.assert_array_equal(hinge_band(share, edges, lengths, width=0.0), share)
    # a crossed edge 40 mm long, longer than the band: its ends inside the
    # band at 0.1 and 0.9 (no edge joins the two pieces), the next ones on them
    out = hinge_band(np.array([0.0, 0.0, 1.0, 1.0]), np.c_[[0, 1, 2], [1, 2, 3]],
                     np.array([0.02, 0.04, 0.02]), width=0.015)
    np.testing.assert_allclose(out, [0.0, 0.1, 0.9, 1.0], atol=1e-12)
    with pytest.raises(ValueError, match="lengths"):
        hinge_band(share, edges, lengths[:-1])


def test_a_shoe_bent_at_the_toe_stretches_over_its_hinge_band_not_one_edge():
    """A shoe's upper 3 cm above the toe joint's axis (x = 0.15), a grid
    5 mm apart, whose skin hands it from the foot (3) to the toes (4)
    between two neighbouring columns. Toes bent down by 0.5 rad: with the
    hinge on that one edge the edge stretches 3.9x; spread over the band
    (``HINGE_BAND``, 15 mm) it stays within the triangle inequality's bound
    1 + max |R p - p| / HINGE_BAND over the band's vertices p (2.1; 2.0
    measured), and the sole and toe cap stay rigid."""
    xs = np.arange(0.0, 0.2501, 0.005)
    gx, gy = np.meshgrid(xs, [0.0, 0.01], indexing="ij")
    pts = np.c_[gx.ravel(), gy.ravel(), np.full(gx.size, 0.03)]
    n = len(xs)
    idx = np.arange(2 * n).reshape(n, 2)
    faces = np.r_[np.c_[idx[:-1, 0], idx[1:, 0], idx[1:, 1]], np.c_[idx[:-1, 0], idx[1:, 1], idx[:-1, 1]]]
    e = mesh_edges(faces)
    lengths = np.linalg.norm(pts[e[:, 1]] - pts[e[:, 0]], axis=1)
    skin = np.zeros((len(pts), 7))
    toe = pts[:, 0] > 0.1525
    skin[toe, 4] = 1.0
    skin[~toe, 3] = 1.0
    mats = np.tile(np.eye(4), (7, 1, 1))
    mats[[4, 5]] = _rot([0, 1, 0], 0.5, np.array([0.15, 0.0, 0.0]))  # toes down: the upper stretches
    ratios = {}
    for name, band in (("edge", None), ("band", (e, lengths))):
        w = articulated_weights(skin, LEG_PARENTS, band=band)
        posed = _skin(pts, w, mats)
        ratios[name] = (np.linalg.norm(posed[e[:, 1]] - posed[e[:, 0]], axis=1) / lengths).max()
        for p in articulated_pieces(w):
            s, r, t = similarity_fit(pts[p], posed[p])
            assert np.linalg.norm(s * pts[p] @ r + t - posed[p], axis=1).max() < 1e-9
    in_band = (w[:, 3] > 0) & (w[:, 4] > 0)
    assert in_band.sum() == 4  # two columns of the grid
    moved = np.linalg.norm(_skin(pts, np.eye(7)[[4] * len(pts)], mats) - pts, axis=1)
    bound = 1.0 + moved[in_band].max() / HINGE_BAND
    assert ratios["edge"] > 3.5, ratios
    assert ratios["band"] <= bound + 1e-9 and bound < 2.2, (ratios, bound)
