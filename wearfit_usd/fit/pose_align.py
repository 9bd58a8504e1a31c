"""Pose and similarity alignment of a rigged reference body onto a target.

Everything is in internal space (Y up, metres) with row-vector 4x4 matrices
(``p' = [p, 1] @ M``), see :mod:`wearfit_usd.transforms`.

* :func:`joint_pairs` maps reference joints to target joints (through
  :func:`wearfit_usd.motion.joint_maps.map_joints`, identical names when it
  pairs nothing).
* :func:`pose_to_target` computes one affine skinning matrix per reference
  joint so that, skinned with the reference's own weights, the body's bones
  line up with the target's bind pose: each joint goes to its mapped target
  joint and each bone is turned (and stretched along its axis) onto the
  target bone.
* :func:`prune_leaf_pairs` drops end-joint pairs whose bone is far from the
  reference's length (a toe joint under the ankle), and
  :func:`refine_end_segments` turns end segments (feet, hands, heads) onto
  the target's matching surface when the bones left them off.
* :func:`similarity_from_pairs` (the Umeyama fit of
  :mod:`wearfit_usd.geometry.mesh` as a 4x4 matrix) and
  :func:`surface_similarity` (PCA + scaled ICP) give global scale + rigid
  alignments.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..geometry.mesh import best_rotation, similarity_fit
from ..motion.joint_maps import map_joints
from ..motion.rig_match import RigMatch, match_skeletons
from ..transforms import rotation_between, rotation_part
from ..types import Matrices4, Matrix4, Points, Scalars

# --------------------------------------------------------------------------
# joint mapping

def _normalise_mapping(result, source_names, target_names) -> list[tuple[int, int]]:
    """Accept the shapes a name mapper may return and give index pairs."""
    src_idx = {n: i for i, n in enumerate(source_names)}
    tgt_idx = {n: i for i, n in enumerate(target_names)}

    def to_idx(v, table, names):
        if v is None:
            return None
        if isinstance(v, (int, np.integer)):
            return int(v) if 0 <= int(v) < len(names) else None
        return table.get(str(v))

    pairs = []
    if hasattr(result, "pairs") and isinstance(result.pairs, dict):
        # joint_maps.JointMapping: pairs = {target name: source name}
        items = [(s, t) for t, s in result.pairs.items()]
    elif isinstance(result, dict):
        items = result.items()
    elif hasattr(result, "pairs"):
        items = result.pairs
    else:
        items = list(result)
        if len(items) == len(source_names) and not all(isinstance(x, (tuple, list)) for x in items
                                                        if x is not None):
            items = list(zip(source_names, items))
    for a, b in items:
        i, j = to_idx(a, src_idx, source_names), to_idx(b, tgt_idx, target_names)
        if i is not None and j is not None:
            pairs.append((i, j))
    return sorted(set(pairs))


def skeleton_match(source, target, user_map: dict | None = None) -> RigMatch:
    """:func:`wearfit_usd.motion.rig_match.match_skeletons` for two
    :class:`~wearfit_usd.model.Skeleton` (their bind positions)."""
    return match_skeletons(source.joint_names, source.parents, source.bind_positions(),
                           target.joint_names, target.parents, target.bind_positions(),
                           user_map=user_map)


def joint_pairs(source_names: list[str], target_names: list[str], source_skeleton=None,
                target_skeleton=None) -> list[tuple[int, int]]:
    """[(source joint index, target joint index)] for joints that correspond.

    With both skeletons (:class:`~wearfit_usd.model.Skeleton`) the pairs come
    from :func:`skeleton_match` (roles from names and structure; exactly the
    name pairs when the name tables pair every key role). Otherwise
    :func:`wearfit_usd.motion.joint_maps.map_joints`; when it fails or pairs
    nothing, joints with identical names are paired.
    """
    if source_skeleton is not None and target_skeleton is not None:
        return skeleton_match(source_skeleton, target_skeleton).index_pairs()
    try:
        pairs = _normalise_mapping(map_joints(list(source_names), list(target_names)),
                                   source_names, target_names)
        if pairs:
            return pairs
    except Exception:  # a mapper failure must not stop fitting
        pass
    tgt = {n: i for i, n in enumerate(target_names)}
    return [(i, tgt[n]) for i, n in enumerate(source_names) if n in tgt]


# --------------------------------------------------------------------------
# similarity transforms

def similarity_from_pairs(src: Points, dst: Points, weights: Scalars | None = None,
                          allow_scale: bool = True) -> Matrix4:
    """Least-squares similarity (Umeyama) taking src onto dst, as a matrix.

    Parameters
    ----------
    src, dst : (n, 3) corresponding points.
    weights : (n,) (None: all equal).
    allow_scale : fit a uniform scale (False: rigid). Coincident source
        points have no scale to measure: the fit is then rigid.

    Returns
    -------
    (4, 4) row-vector matrix ``M`` with ``dst ~ [src, 1] @ M``: the
    :func:`~wearfit_usd.geometry.mesh.similarity_fit` in matrix form.
    """
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    allow_scale = allow_scale and bool(np.ptp(src, axis=0).any())
    scale, r, t = similarity_fit(src, dst, weights, scale=allow_scale)
    m = np.eye(4)
    m[:3, :3] = scale * r
    m[3, :3] = t
    return m


def apply(m: Matrix4, points: Points) -> Points:
    """(n, 3) points mapped by the (4, 4) row-vector matrix ``m``."""
    return points @ m[:3, :3] + m[3, :3]


def surface_similarity(src: Points, dst: Points, iterations: int = 30,
                       sample: int = 4000, seed: int = 0) -> tuple[Matrix4, float]:
    """Similarity alignment of point set src onto point set dst without any
    correspondence: centroid + RMS-radius scale, PCA axes (the four proper
    sign choices are tried) refined by symmetric scaled ICP.

    Returns ((4, 4) matrix, RMS residual in dst units).
    """
    rng = np.random.default_rng(seed)
    s_pts = src[rng.choice(len(src), min(sample, len(src)), replace=False)]
    d_pts = dst[rng.choice(len(dst), min(sample, len(dst)), replace=False)]
    cs, cd = src.mean(0), dst.mean(0)
    rs = np.sqrt(np.mean(np.sum((src - cs) ** 2, 1)))
    rd = np.sqrt(np.mean(np.sum((dst - cd) ** 2, 1)))
    _, _, vs = np.linalg.svd(src - cs, full_matrices=False)
    _, _, vd = np.linalg.svd(dst - cd, full_matrices=False)
    tree_d = cKDTree(dst)
    best = (np.inf, np.eye(4))
    candidates = [np.eye(3)]
    for signs in ([1, 1, 1], [-1, -1, 1], [-1, 1, -1], [1, -1, -1]):
        r = vs.T @ np.diag(signs) @ vd  # row-vector: src axes -> dst axes
        if np.linalg.det(r) < 0:
            r = vs.T @ np.diag(signs) @ np.diag([1, 1, -1]) @ vd
        candidates.append(r)
    for r in candidates:
        m = np.eye(4)
        m[:3, :3] = (rd / rs) * r
        m[3, :3] = cd - (rd / rs) * cs @ r
        for _ in range(iterations):
            moved = apply(m, s_pts)
            _, i_fwd = tree_d.query(moved)
            tree_s = cKDTree(moved)
            _, i_bwd = tree_s.query(d_pts)
            a = np.concatenate([s_pts, s_pts[i_bwd]])
            b = np.concatenate([dst[i_fwd], d_pts])
            m = similarity_from_pairs(a, b)
        moved = apply(m, s_pts)
        d1, _ = tree_d.query(moved)
        d2, _ = cKDTree(moved).query(d_pts)
        err = float(np.sqrt(0.5 * (np.mean(d1 ** 2) + np.mean(d2 ** 2))))
        if err < best[0]:
            best = (err, m)
    return best[1], best[0]


# --------------------------------------------------------------------------
# pose alignment through the skeletons

def _mapped_descendants(children, mapped, j):
    """Nearest mapped joints below j (the search stops at each mapped one)."""
    out, stack = [], list(children[j])
    while stack:
        c = stack.pop()
        if mapped[c]:
            out.append(c)
        else:
            stack.extend(children[c])
    return out


def pose_to_target(ref_bind: Matrices4, ref_parents: np.ndarray, target_bind: Matrices4,
                   pairs: list[tuple[int, int]], stretch: bool = True,
                   frame_tolerance_deg: float = 20.0) -> dict:
    """Skinning matrices that pose the reference rig onto the target rig.

    ref_bind (J, 4, 4), target_bind (Jt, 4, 4): bind world transforms
    (internal). ref_parents (J,). pairs: [(ref joint, target joint)].

    Per reference joint j a 3x3 ``A_j = s * S_j @ D_j`` (global scale s,
    stretch S_j along the reference bone, rotation D_j) and its new position
    P'_j; skinning matrix ``M_j`` maps ``p -> (p - P_j) @ A_j + P'_j``.
    D_j turns the bone towards its mapped descendants (one: smallest
    rotation after the parent's turn, or the bind-frame change when the two
    rigs' frames agree within ``frame_tolerance_deg``; several: Kabsch).
    Unmapped joints ride rigidly on their parent.

    Returns dict: ``skin`` (J, 4, 4) skinning matrices, ``world`` (J, 4, 4)
    orthonormal posed joint transforms (new bind pose for the fitted body),
    ``similarity`` (4, 4) global similarity from the joint pairs,
    ``n_pairs``.
    """
    n = len(ref_parents)
    P = ref_bind[:, 3, :3]
    Q = target_bind[:, 3, :3]
    Rr = rotation_part(ref_bind)
    Rt = rotation_part(target_bind)
    mapping = np.full(n, -1)
    for i, j in pairs:
        mapping[i] = j
    mapped = mapping >= 0
    children = [[] for _ in range(n)]
    for j, p in enumerate(ref_parents):
        if p >= 0:
            children[p].append(j)
    idx = np.flatnonzero(mapped)
    if len(idx) >= 3:
        sim = similarity_from_pairs(P[idx], Q[mapping[idx]])
    elif len(idx) >= 1:
        sim = np.eye(4)
        sim[3, :3] = (Q[mapping[idx]] - P[idx]).mean(0)
    else:
        sim = np.eye(4)
    g_scale = float(np.cbrt(np.linalg.det(sim[:3, :3])))
    g_rot = sim[:3, :3] / g_scale
    cos_tol = np.cos(np.radians(frame_tolerance_deg))

    A = np.zeros((n, 3, 3))
    D = np.zeros((n, 3, 3))
    newP = np.zeros((n, 3))
    for j in range(n):
        p = ref_parents[j]
        d_parent = g_rot if p < 0 else D[p]
        if mapped[j]:
            newP[j] = Q[mapping[j]]
        elif p >= 0:
            newP[j] = (P[j] - P[p]) @ A[p] + newP[p]
        else:
            newP[j] = apply(sim, P[j][None])[0]
        desc = _mapped_descendants(children, mapped, j) if mapped[j] else []
        dr = P[desc] - P[j] if desc else np.zeros((0, 3))
        dt = Q[mapping[desc]] - Q[mapping[j]] if desc else np.zeros((0, 3))
        keep = (np.linalg.norm(dr, axis=1) > 1e-6) & (np.linalg.norm(dt, axis=1) > 1e-6)
        dr, dt = dr[keep], dt[keep]
        stretch_m = np.eye(3)
        d_frame = Rr[j].T @ Rt[mapping[j]] if mapped[j] else None
        if len(dr) == 1:
            u = dr[0] / np.linalg.norm(dr[0])
            v = dt[0] / np.linalg.norm(dt[0])
            base = d_parent
            if d_frame is not None and float(u @ d_frame @ v) > cos_tol:
                base = d_frame
            D[j] = base @ rotation_between(u @ base, v)
            if stretch:
                k = float(np.clip(np.linalg.norm(dt[0]) / (g_scale * np.linalg.norm(dr[0])), 0.5, 2.0))
                stretch_m = np.eye(3) + (k - 1.0) * np.outer(u, u)
        elif len(dr) >= 2:
            a = dr / np.linalg.norm(dr, axis=1, keepdims=True)
            b = dt / np.linalg.norm(dt, axis=1, keepdims=True)
            w = np.linalg.norm(dr, axis=1)
            D[j] = best_rotation((a * w[:, None]).T @ b)[0]  # Kabsch, about the joint
        else:
            D[j] = d_parent
            if d_frame is not None:
                # a mapped leaf (head, toes): trust the target frame if it is
                # close to what the parent's turn gives
                rel = d_parent.T @ d_frame
                if (np.trace(rel) - 1) / 2 > cos_tol:
                    D[j] = d_frame
        A[j] = g_scale * stretch_m @ D[j]
    skin = np.tile(np.eye(4), (n, 1, 1))
    skin[:, :3, :3] = A
    skin[:, 3, :3] = newP - np.einsum("ni,nij->nj", P, A)
    world = np.tile(np.eye(4), (n, 1, 1))
    world[:, :3, :3] = Rr @ D
    world[:, 3, :3] = newP
    return {"skin": skin, "world": world, "similarity": sim, "n_pairs": int(mapped.sum()),
            "positions": newP}


# --------------------------------------------------------------------------
# end joints placed unlike a human's

def prune_leaf_pairs(ref_bind: Matrices4, ref_parents: np.ndarray, target_bind: Matrices4,
                     pairs: list[tuple[int, int]], ratio: tuple[float, float] = (0.7, 1.4),
                     min_length: float = 0.04) -> tuple[list[tuple[int, int]], list[int]]:
    """Unpair end joints whose bone would squash or stretch their segment.

    An end joint (mapped, nothing mapped below it) gives the direction and
    length of the bone from its nearest mapped ancestor. Some rigs place it
    unlike a human's: a low-poly figure's "toe" joint sits under the ankle
    (the bone 0.072 m long, pointing into the floor, where a human foot is
    0.14 m to the ball); posed on it, the foot is squashed to 60 % and turned
    down, and the toes stay 10 cm short of the target's (RiggedFigure fit,
    target->fit surface p99: 104 mm with the pair, 18 mm without it and the
    foot turned by :func:`refine_end_segments`). When that bone's length, over the
    reference's times the global scale of the joint pairs, leaves ``ratio``
    the pair is dropped: the segment keeps its shape and turns with its
    parent (:func:`pose_to_target`), and the non-rigid fit places it. Bones
    under ``min_length`` x the reference skeleton's extent (finger tips) keep
    their pairs: their segments are too small to matter and free ones fold.

    ref_bind (J, 4, 4), ref_parents (J,), target_bind (Jt, 4, 4); pairs
    [(ref joint, target joint)]. Returns (kept pairs, dropped reference
    joints).
    """
    n = len(ref_parents)
    mapping = np.full(n, -1)
    for i, j in pairs:
        mapping[i] = j
    mapped = mapping >= 0
    idx = np.flatnonzero(mapped)
    if len(idx) < 3:
        return list(pairs), []
    P = ref_bind[:, 3, :3]
    Q = target_bind[:, 3, :3]
    sim = similarity_from_pairs(P[idx], Q[mapping[idx]])
    scale = float(np.cbrt(np.linalg.det(sim[:3, :3])))
    children = [[] for _ in range(n)]
    for j, p in enumerate(ref_parents):
        if p >= 0:
            children[p].append(j)
    extent = float(np.linalg.norm(np.ptp(P, axis=0)))
    dropped = []
    for leaf in idx:
        if _mapped_descendants(children, mapped, leaf):
            continue
        anc = ref_parents[leaf]
        while anc >= 0 and not mapped[anc]:
            anc = ref_parents[anc]
        if anc < 0:
            continue
        lr = scale * float(np.linalg.norm(P[leaf] - P[anc]))
        lt = float(np.linalg.norm(Q[mapping[leaf]] - Q[mapping[anc]]))
        if lr > min_length * extent * scale and not ratio[0] <= lt / lr <= ratio[1]:
            dropped.append(int(leaf))
    return [p for p in pairs if p[0] not in dropped], dropped


# --------------------------------------------------------------------------
# end segments turned onto the target surface

def _subtree(parents: np.ndarray, j: int) -> np.ndarray:
    """(J,) bool: joint j and every joint below it (parents[k] < k)."""
    inside = np.zeros(len(parents), bool)
    inside[j] = True
    for k in range(j + 1, len(parents)):
        if parents[k] >= 0 and inside[parents[k]]:
            inside[k] = True
    return inside


def _dominant(joint_indices: np.ndarray, joint_weights: np.ndarray) -> np.ndarray:
    return joint_indices[np.arange(len(joint_indices)), np.argmax(joint_weights, axis=1)]


def _turn_about(src: Points, dst: Points, centre: np.ndarray, iterations: int = 12):
    """Rotation about ``centre`` taking point set src onto point set dst
    (symmetric closest-point ICP, no correspondence given):
    :func:`_turn_scale_about` with the scale held at 1 (identity axes, on
    which its products are exact).

    Returns ((3, 3) row-vector rotation, RMS before, RMS after)."""
    _, rot, _, before, after = _turn_scale_about(src, dst, centre, np.eye(3), scale_range=(1.0, 1.0),
                                                 iterations=iterations)
    return rot, before, after


def _angle(rot: np.ndarray) -> float:
    """Degrees turned by a (3, 3) rotation."""
    return float(np.degrees(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1, 1))))


def _turn_scale_about(src: Points, dst: Points, centre: np.ndarray, axes: np.ndarray,
                      scale_range: tuple[float, float] = (0.67, 1.6), iterations: int = 30,
                      turn: bool = True):
    """Rotation followed by a scale along three axes, about ``centre``,
    taking point set src onto point set dst (symmetric closest-point ICP).

    The map is ``p -> (p - c) @ R @ M + c`` with ``M = axes.T @ diag(s) @
    axes``: src turned by R (3, 3), then stretched by s_k along the rows of
    ``axes`` (3, 3) orthonormal (the target segment's principal axes), each
    s_k clipped to ``scale_range``. With the correspondences fixed, R is the
    Kabsch rotation of src onto dst with the current scale undone, and s_k
    the least-squares ratio of the turned src to dst along axis k.

    Returns ((3, 3) row-vector linear map R @ M, R, s (3,), RMS before, RMS
    after).
    """
    tree_d = cKDTree(dst)
    a0 = src - centre
    b0 = dst - centre
    rot = np.eye(3)
    s = np.ones(3)

    def linear(r, sc):
        return r @ (axes.T * sc) @ axes

    def rms(lin):
        moved = a0 @ lin + centre
        d1, _ = tree_d.query(moved)
        d2, _ = cKDTree(moved).query(dst)
        return float(np.sqrt(0.5 * (np.mean(d1 ** 2) + np.mean(d2 ** 2))))

    before = rms(np.eye(3))
    for _ in range(iterations):
        moved = a0 @ linear(rot, s) + centre
        _, i_f = tree_d.query(moved)
        _, i_b = cKDTree(moved).query(dst)
        a = np.concatenate([a0, a0[i_b]])
        b = np.concatenate([b0[i_f], b0])
        unscaled = b @ (axes.T / s) @ axes
        if turn:
            rot = best_rotation(a.T @ unscaled)[0]
        ar = a @ rot @ axes.T
        bf = b @ axes.T
        s = np.clip((ar * bf).sum(0) / np.maximum((ar * ar).sum(0), 1e-12), *scale_range)
    lin = linear(rot, s)
    return lin, rot, s, before, rms(lin)


def refine_end_segments(posed: Points, joint_indices: np.ndarray, joint_weights: np.ndarray,
                        world: Matrices4, skin: Matrices4, ref_parents: np.ndarray,
                        target_points: Points, target_joint_indices: np.ndarray,
                        target_joint_weights: np.ndarray, target_parents: np.ndarray,
                        pairs: list[tuple[int, int]], target_faces: np.ndarray | None = None,
                        min_gain: float = 0.3, min_fraction: float = 0.03,
                        max_angle_deg: float = 45.0,
                        min_angle_deg: float = 8.0, sample: int = 1500, scale: bool = True,
                        min_scale_change: float = 0.1, min_scale_gain: float = 0.3,
                        scale_min_residual: float = 0.02,
                        scale_range: tuple[float, float] = (0.5, 3.0)) -> tuple[Matrices4, Matrices4, list]:
    """Turn end segments (feet with their toes, hands, heads) about their
    mapped joint so their surface lies on the target's matching segment.

    Bones give a segment's position but not always its direction: a toe
    joint placed under the ankle (a low-poly figure's foot bone points
    into the floor) turns a posed foot down by tens of degrees, out of reach
    of the non-rigid step's closest points. For every mapped joint whose
    mapped descendants (if any) are all leaves, the reference vertices
    skinned mostly by its subtree are matched to the target vertices skinned
    mostly by the mapped target joint's subtree by a rotation about the
    posed joint (symmetric ICP). The turn is kept only when it lowers the
    RMS distance by more than ``min_gain`` (a fraction) and exceeds
    ``min_angle_deg``: where the pose step already agrees (the MakeHuman
    bodies) nothing changes.

    Stylised figures also differ in size per segment (GDQuest's mannequin:
    a head 1.6-1.9x the reference's, toe caps three times as long as its
    toes; Khronos' RiggedFigure: a box head twice the size): a bone's length
    gives no measure of them, and the non-rigid step then stretches a small
    head or foot over a big one, leaving hats over the eyes and toes out of
    the shoes. With ``scale``, the segment is also matched by a turn
    followed by a stretch along the target segment's principal axes
    (:func:`_turn_scale_about`, each factor within ``scale_range``; a
    stretch alone when the turn found is over ``max_angle_deg``), kept only
    when it lowers the RMS by ``min_scale_gain`` more than the turn alone (which
    is itself kept when it qualifies as above), and only where the turn
    leaves an RMS over ``scale_min_residual`` x the body's height (the
    MakeHuman bodies' segments: at most 28 mm; the figures' 36-132 mm) and
    no factor stopped at an end of ``scale_range`` (no size found). A
    scale changes the joints' positions below the segment, not their
    (orthonormal) frames.

    posed (N, 3) posed reference points; joint_indices/joint_weights (N, K);
    world, skin (J, 4, 4) posed joint transforms and skinning matrices from
    :func:`pose_to_target`; target_points (M, 3) with (M, K') influences.
    Returns (world, skin, [(ref joint, degrees, (3,) scale factors)] of the
    changes made).
    """
    world = world.copy()
    skin = skin.copy()
    posed = np.array(posed, dtype=float)
    n = len(ref_parents)
    mapping = np.full(n, -1)
    for i, j in pairs:
        mapping[i] = j
    children = [[] for _ in range(n)]
    for j, p in enumerate(ref_parents):
        if p >= 0:
            children[p].append(j)
    dom_r = _dominant(joint_indices, joint_weights)
    dom_t = _dominant(target_joint_indices, target_joint_weights)
    rng = np.random.default_rng(0)
    if target_faces is not None:
        # a low-poly target has a few dozen vertices per segment: match
        # against area-uniform samples of its surface instead
        f = np.asarray(target_faces)
        tri = np.asarray(target_points)[f]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        m = 20 * len(f) if len(target_points) < 20000 else 0
        if m and area.sum() > 0:
            t = rng.choice(len(f), size=min(m, 200000), p=area / area.sum())
            r1, r2 = rng.random(len(t)), rng.random(len(t))
            sq = np.sqrt(r1)
            b = np.stack([1 - sq, sq * (1 - r2), sq * r2], axis=1)
            target_points = np.einsum("mk,mkj->mj", b, tri[t])
            dom_t = dom_t[f[t, np.argmax(b, axis=1)]]
    height = float(np.ptp(posed, axis=0).max())
    turns = []
    for j in range(n):
        if mapping[j] < 0:
            continue
        desc = _mapped_descendants(children, mapping >= 0, j)
        if any(_mapped_descendants(children, mapping >= 0, d) for d in desc):
            continue  # not an end segment
        sub_r = _subtree(ref_parents, j)
        sub_t = _subtree(target_parents, int(mapping[j]))
        vr = np.flatnonzero(sub_r[dom_r])
        vt = np.flatnonzero(sub_t[dom_t])
        if len(vr) < max(8, min_fraction * len(posed)) or len(vt) < 8:
            continue  # fingers and other small parts follow their parent
        vr = vr if len(vr) <= sample else rng.choice(vr, sample, replace=False)
        vt = vt if len(vt) <= sample else rng.choice(vt, sample, replace=False)
        centre = world[j, 3, :3]
        rot, before, after = _turn_about(posed[vr], target_points[vt], centre)
        lin, s = rot, np.ones(3)
        # what the turn leaves (all of it when the turn found is implausible)
        turned = before if _angle(rot) > max_angle_deg else after
        if scale and turned > scale_min_residual * height:
            # a scale as well only where the segment is centimetres off after
            # the turn and the scale explains much more of it (a stylised
            # figure's big head or toe caps, not one MakeHuman body's against
            # another's: their residuals are under 28 mm, the figures' 36-132)
            tp = target_points[vt]
            axes = np.linalg.svd(tp - tp.mean(0), full_matrices=False)[2]
            fit = _turn_scale_about(posed[vr], tp, centre, axes, scale_range=scale_range)
            if _angle(fit[1]) > max_angle_deg:
                fit = _turn_scale_about(posed[vr], tp, centre, axes, scale_range=scale_range,
                                        turn=False)
            # a factor stopped at the range's end is no size found (GDQuest's
            # toe caps: 3 / 3 / 0.5 flattened the toes into a slab the shoes
            # crumpled on, shoes01's stretch max 2.8 -> 5.1 in a walk)
            inside = np.all((fit[2] > scale_range[0] + 1e-6) & (fit[2] < scale_range[1] - 1e-6))
            if inside and fit[4] < (1.0 - min_scale_gain) * turned:
                lin, rot, s, _, after = fit
        angle = _angle(rot)
        changed = angle >= min_angle_deg or float(np.abs(s - 1).max()) >= min_scale_change
        if after > (1.0 - min_gain) * before or angle > max_angle_deg or not changed:
            continue
        turn = np.eye(4)
        turn[:3, :3] = lin
        turn[3, :3] = centre - centre @ lin
        world[sub_r, 3, :3] = world[sub_r, 3, :3] @ lin + turn[3, :3]
        world[sub_r, :3, :3] = world[sub_r, :3, :3] @ rot
        skin[sub_r] = skin[sub_r] @ turn
        moved = sub_r[dom_r]
        posed[moved] = posed[moved] @ lin + turn[3, :3]
        turns.append((j, round(angle, 1), tuple(round(float(v), 2) for v in s)))
    return world, skin, turns
