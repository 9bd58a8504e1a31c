"""Skin weights for dressed items, derived from their K-triangle binding.

An item vertex bound to K body triangles with blend weights ``w_k`` and
local coordinates ``(a, b, c)`` (:class:`binding.Binding`) sits over the
point ``(1 - a - b) v1 + a v2 + b v3`` of each triangle. Its skin weights
are the bound triangles' vertex weights blended by these coordinates
(clamped to the triangle) times ``w_k ** BLEND_POWER`` (renormalised), so
the item is skinned the way the skin under it is, the nearest triangles
counting most. (With ``w_k`` itself the blend reached across a joint's
crease: a sleeve's underarm, over skin 0.88-1.0 on the upper arm, took
0.14-0.27 of the chest's weight from the torso's triangles across the
armpit, and in the CMU run its skinned copy went 10-22 mm into the skin
under the arm.) The strongest ``max_influences`` (default 8) are kept and
renormalised. Skirt parts, bound to the hips, take the skin weights of the
torso and leg on their side (:mod:`skirt_weights`). Rigid parts
(:mod:`rigid_parts`: shoes, hats, glasses, short hair) are *articulated*
when the skeleton's ``parents`` are given (:func:`articulated_weights`):
the part's principal joint (a shoe's foot) carries the vertices the skin
under them gives mostly to it, a child joint
(the toes) those it gives mostly to that child's subtree, the principal's
parent (the calf) the collar, with linear hinges between (``HINGE``). The
sole, the toe cap and the collar each move rigidly and the shoe bends at the
joints only; a hat or glasses come out on the head alone, short hair with
its nape on the neck. Without ``parents`` a part whose bound body patch
follows one joint (``ONE_JOINT_SHARE`` of its weight) is skinned to that
joint alone, and any other keeps the per-vertex weights of the skin under
it, bending wherever the skin does (on the CMU walk a shoe's pieces were
then 42-67 mm off any similarity transform in the worst frame).

Arrays are numpy; body weights are (N, K) joint indices and weights into a
skeleton of ``n_joints`` joints, on the body topology the binding indexes.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..geometry.closest import SurfaceQuery
from ..geometry.mesh import edges as mesh_edges
from ..geometry.mesh import same_topology
from ..model import SKINNED_SUFFIX  # noqa: F401 (re-exported: the skinned copies' names)
from .binding import Binding
from .regions import weight_region_shares
from .skirt_weights import LegSkin, has_leg_skin, hip_axes, skirt_weights

MAX_INFLUENCES = 8
#: a rigid group whose body patch has this share of one joint's weight is
#: skinned to that joint alone
ONE_JOINT_SHARE = 0.9
#: articulated rigid parts: a vertex's weight on a piece other than the
#: principal joint's (its share of that piece's joints in the skin under
#: it) below HINGE[0] goes to the principal joint, above HINGE[1] wholly to
#: that piece, and rises linearly between (the hinge). Measured on the CMU
#: walk, shoes01 on body_male_heavy: (0.25, 0.75) with a smoothstep rise
#: left edges stretched 1.26x beyond the skin's at p99, (0.1, 0.9) linear
#: 1.01x; 61 % of shoes02's vertices are then in rigid pieces
HINGE = (0.1, 0.9)
#: a vertex at least this much on one joint belongs to that joint's rigid
#: piece (:func:`articulated_pieces`)
PIECE_WEIGHT = 1.0 - 1e-9
#: articulated rigid parts given their mesh: the hinge between the
#: principal joint's piece and a child's (a shoe's toe cap) spans this width
#: (metres, along the part's surface) centred on where the skin's share
#: crosses 1/2 (:func:`hinge_band`). The share had jumped from the sole to
#: the toe cap between two shoe vertices 6 mm apart, and that edge
#: stretched 2.4x in the CMU run. Worst stretch beyond the skin's (shoes02
#: on body_female_thin; run, pirouette, arms held high, walk): no band
#: 2.35 / 2.39 / 1.56 / 1.95; 0.01 m 1.49 / 1.71 / 1.60 / 1.31; 0.015 m
#: 1.35 / 1.56 / 1.56 / 1.27; 0.02 m 1.45 / 1.99 / 1.70 / 1.18; 0.03 m
#: 1.63 / 2.25 / 1.96 / 1.20 (wider bands reach skin that stays rigid)
HINGE_BAND = 0.015
#: the skin weights blend the K bound triangles by their binding weights to
#: this power (renormalised); rigid parts keep the plain blend (power 1: their
#: hinges were measured with it). female_casualsuit01's skinned copy on
#: body_female_thin, worst frame's new penetrations (the redress): CMU run
#: 1.61 % (0.26) at power 1, 0.88 % at 2, 0.31 % on the nearest triangle
#: alone; jump 1.92 / 0.73 / 0.21 % (0.21); but posed by UsdSkel in the
#: walk's first 15 frames, counting every vertex under the skin, 1.27 / 1.05 /
#: 1.87 % (the redress 0.41): the nearest triangle alone follows the skin's
#: own pinching, its neighbours come over the vertex
BLEND_POWER = 2.0


def binding_coefficients(binding: Binding, n_body: int, power: float = 1.0) -> sp.csr_matrix:
    """(M, N) non-negative coefficients of each item vertex on the body
    vertices, rows summing to 1.

    Parameters
    ----------
    binding : Binding
        ``triangles`` (M, K), ``weights`` (M, K), ``local`` (M, K, 3).
    n_body : int
        Number of body vertices N.
    power : float
        The triangles' blend weights are raised to this power (and
        renormalised): above 1 the nearest triangles count more.

    Returns
    -------
    scipy.sparse.csr_matrix
        (M, N): per bound triangle, its clamped barycentric coordinates
        ``(1 - a - b, a, b)`` times the triangle's blend weight (to ``power``).
    """
    if power <= 0:
        raise ValueError(f"blend power {power}: expected > 0")
    tri = np.asarray(binding.triangles)
    local = np.asarray(binding.local)
    blend = np.asarray(binding.weights, dtype=np.float64) ** power
    m, k = tri.shape
    a = local[..., 0]
    b = local[..., 1]
    bary = np.clip(np.stack([1.0 - a - b, a, b], axis=-1), 0.0, None)  # (M, K, 3)
    s = bary.sum(axis=-1, keepdims=True)
    bary = np.where(s > 1e-12, bary / np.maximum(s, 1e-12), 1.0 / 3.0)
    vals = bary * blend[..., None]
    cols = np.asarray(binding.faces)[tri]  # (M, K, 3)
    rows = np.repeat(np.arange(m), k * 3)
    c = sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(m, n_body))
    c.sum_duplicates()
    norm = np.asarray(c.sum(axis=1)).ravel()
    return sp.diags(1.0 / np.maximum(norm, 1e-12)) @ c


def weight_matrix(joint_indices: np.ndarray, joint_weights: np.ndarray, n_joints: int) -> sp.csr_matrix:
    """(N, K) influences -> (N, J) sparse weight matrix (duplicates summed)."""
    ji = np.asarray(joint_indices, dtype=np.int64)
    n, k = ji.shape
    w = sp.csr_matrix((np.asarray(joint_weights, dtype=np.float64).ravel(),
                       (np.repeat(np.arange(n), k), ji.ravel())), shape=(n, n_joints))
    w.sum_duplicates()
    return w


def prune(weights, max_influences: int = MAX_INFLUENCES):
    """The strongest ``max_influences`` of each row of an (M, J) weight
    matrix (dense or sparse), renormalised.

    Returns
    -------
    (M, min(max_influences, J)) int64 joint indices, strongest first, and
    float64 weights (rows sum to 1; unused slots have weight 0).
    """
    dense = weights.toarray() if sp.issparse(weights) else np.asarray(weights, dtype=np.float64)
    dense = np.clip(dense, 0.0, None)
    k = min(max_influences, dense.shape[1])
    if k < dense.shape[1]:
        idx = np.argpartition(-dense, k - 1, axis=1)[:, :k]
    else:
        idx = np.broadcast_to(np.arange(k), dense.shape).copy()
    w = np.take_along_axis(dense, idx, axis=1)
    order = np.argsort(-w, axis=1, kind="stable")
    idx = np.take_along_axis(idx, order, axis=1)
    w = np.take_along_axis(w, order, axis=1)
    s = w.sum(axis=1, keepdims=True)
    if (s <= 1e-12).any():
        raise ValueError(f"{int((s <= 1e-12).sum())} item vertices got no skin weight")
    return idx.astype(np.int64), w / s


def piece_joints(parents: np.ndarray, principal: int) -> np.ndarray:
    """(J,) the articulated piece each joint belongs to for a rigid part
    carried by joint ``principal`` (a shoe's foot): the direct child of
    ``principal`` whose subtree holds the joint (the toe cap: a toe's
    further segments go to the first), ``principal`` itself, or else the
    parent of ``principal`` (the collar on the calf: every joint outside
    ``principal``'s subtree). ``parents`` (J,) with ``parents[j] < j``, -1
    for a root."""
    parents = np.asarray(parents, dtype=np.int64)
    up = int(parents[principal])
    rest = up if up >= 0 else principal
    piece = np.full(len(parents), rest, dtype=np.int64)
    piece[principal] = principal
    for j, p in enumerate(parents):  # parents first: piece[p] is final
        if j == principal:
            continue
        if p == principal:
            piece[j] = j
        elif p >= 0 and piece[p] != rest and p != up:
            piece[j] = piece[p]
    return piece


def hinge_band(share: np.ndarray, edges: np.ndarray, lengths: np.ndarray, width: float = HINGE_BAND) -> np.ndarray:
    """A piece's share (P,) of a rigid part's vertices, rising over a band
    ``width`` wide along the part's surface.

    The line where ``share`` crosses 1/2 is found on the part's edges
    (linearly between the two ends of each edge it crosses); each vertex's
    distance ``d`` to it along the edges (Dijkstra) gives the new share
    ``clip(1/2 + s d / width, 0, 1)``, ``s`` = +1 on the piece's side
    (``share >= 1/2``) and -1 on the other; the two ends of a crossed edge
    longer than ``width`` get ``clip(1/2 + s d / max(width, d / 0.4))``,
    0.1 and 0.9 at most, so that no edge joins the two pieces directly. A
    shoe then bends at the toe over ``width`` of its upper and sole, not
    over one edge, so its edges stretch no more than the skin they cover:
    bending by an angle ``a`` with the surface ``h`` from the joint's axis
    lengthens (or shortens) the band by about ``a h``, i.e. by
    ``a h / width`` of its length.

    Parameters
    ----------
    share : (P,) array in [0, 1]
    edges : (E, 2) int array of indices into ``share``
    lengths : (E,) array of the edges' lengths
    width : float
        The band's width (``HINGE_BAND``); 0 returns ``share`` unchanged.

    Returns
    -------
    (P,) float64 shares; vertices of a connected piece of the part that the
    line does not cross keep theirs.
    """
    share = np.asarray(share, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    lengths = np.asarray(lengths, dtype=np.float64)
    if len(lengths) != len(edges):
        raise ValueError(f"{len(edges)} edges but {len(lengths)} lengths")
    if width < 0:
        raise ValueError(f"hinge band width {width}: expected >= 0")
    p = len(share)
    if width == 0 or len(edges) == 0:
        return share.copy()
    a, b = edges[:, 0], edges[:, 1]
    inside = share >= 0.5
    cross = inside[a] != inside[b]
    if not cross.any():
        return share.copy()
    ca, cb, cl = a[cross], b[cross], lengths[cross]
    t = (0.5 - share[ca]) / (share[cb] - share[ca])  # where 1/2 is crossed along a -> b, in [0, 1]
    start = np.full(p, np.inf)
    np.minimum.at(start, ca, t * cl)
    np.minimum.at(start, cb, (1.0 - t) * cl)
    # one extra node p reaching each crossed edge's ends at their distance
    # to the crossing (an explicit zero would read as no edge: floored)
    src = np.flatnonzero(np.isfinite(start))
    graph = sp.csr_matrix((np.concatenate([lengths, lengths, np.maximum(start[src], 1e-12)]),
                           (np.concatenate([a, b, np.full(len(src), p)]),
                            np.concatenate([b, a, src]))), shape=(p + 1, p + 1))
    d = dijkstra(graph, directed=True, indices=p)[:p]
    # the ends of a crossed edge longer than the band stay inside it (at
    # 0.1 and 0.9 at most), not on the pieces: a shoe's 22 mm sole edge
    # then bends over three edges, not one
    w = np.full(p, float(width))
    w[src] = np.maximum(width, start[src] / 0.4)
    out = np.clip(0.5 + np.where(inside, d, -d) / w, 0.0, 1.0)
    return np.where(np.isfinite(d), out, share)


def articulated_weights(weights: np.ndarray, parents: np.ndarray, hinge: tuple | None = None,
                        band: tuple | None = None) -> np.ndarray:
    """Skin weights that move a rigid part as articulated rigid pieces.

    The part's principal joint j0 is the one with the largest total weight
    (a shoe's foot). Each vertex's weights are summed per piece
    (:func:`piece_joints`: j0, a direct child of j0 with its subtree, or
    j0's parent with the rest); a piece's sum ``s`` other than j0's becomes
    ``clip((s - lo) / (hi - lo), 0, 1)`` (``hinge``) and j0 takes the rest;
    the parent piece's share is then spread over that piece's joints in the
    proportions of the skin under the vertex. Vertices away from the hinges
    are then on one joint (the parent piece's: on as many as the skin under
    them): LBS moves each piece by that joint's transform alone, rigidly,
    and the part bends at the hinges only (a shoe at the toe joint and at
    the collar; the skin's own weights, wider blends over calf, foot and
    toes, left its pieces 42-67 mm off any similarity transform in the CMU
    walk).

    Parameters
    ----------
    weights : (P, J) array
        The part's vertices' weights (rows summing to 1).
    parents : (J,) int array
        The skeleton's parents (``parents[j] < j``).
    hinge : (lo, hi)
        Where a child's share starts and ends its rise.
    band : ((E, 2) int array, (E,) array), optional
        The part's edges (indices into the rows of ``weights``) and their
        lengths: the shares of j0's children (a shoe's toes) then rise over
        ``HINGE_BAND`` of the part's surface (:func:`hinge_band`) instead
        of where the skin's does; the parent's (the collar's) is kept.

    Returns
    -------
    (P, J) float64 weights, rows summing to 1, non-zero on j0, its direct
    children and the joints of its parent's piece only (the parent piece's
    share spread over them as the skin under the vertex spreads it: a
    collar on the calf alone, a nape on the neck joints it lies on).
    """
    w = np.asarray(weights, dtype=np.float64)
    parents = np.asarray(parents, dtype=np.int64)
    if w.ndim != 2 or w.shape[1] != len(parents):
        raise ValueError(f"weights {w.shape} do not match {len(parents)} joints")
    hinge = HINGE if hinge is None else hinge
    lo, hi = hinge
    if not 0.0 <= lo < hi <= 1.0:
        raise ValueError(f"hinge {hinge}: expected 0 <= lo < hi <= 1")
    j0 = int(np.argmax(w.sum(axis=0)))
    piece = piece_joints(parents, j0)
    summed = np.zeros_like(w)
    np.add.at(summed.T, piece, w.T)  # summed[:, c] = sum of w[:, j] over piece[j] == c
    out = np.clip((summed - lo) / (hi - lo), 0.0, 1.0)
    out[:, j0] = 0.0
    if band is not None:
        # the toes' hinge only: the collar's share (the calf's) rises over
        # the ankle's wide blend; a band centred on its middle made the
        # shoes' stretch p99 1.03-1.11 -> 1.3-1.8 and new penetrations up
        # to 4.5 % (CMU clips, shoes02 on body_female_thin)
        for c in np.flatnonzero((out.max(axis=0) > 0.0) & (parents == j0)):
            out[:, c] = hinge_band(out[:, c], band[0], band[1], width=HINGE_BAND)
    s = out.sum(axis=1)
    over = s > 1.0  # two pieces each over its hinge's start (a vertex between toes)
    out[over] /= s[over, None]
    out[:, j0] = 1.0 - out.sum(axis=1)
    up = int(parents[j0])
    if up >= 0:
        # the parent's piece rides the joints the skin under it rides, in
        # the skin's proportions: on a CMU-style neck (Neck, Neck1, Head) the
        # nape's skin is 0.58 Neck and 0.36 Neck1, and short hair's nape on
        # Neck1 alone sank 1-2.5 mm into it in the walk (skinned copy, 2.25 %
        # new penetrations against the redress's 0 %, body_male_cmu_rig)
        cols = np.flatnonzero(piece == up)
        parts = w[:, cols]
        total = parts.sum(axis=1)
        rows = np.flatnonzero((out[:, up] > 0.0) & (total > 0.0))
        # the fractions first: a vertex on one joint of the piece gets
        # exactly 1.0 there, so its share moves whole to that joint (on the
        # parent itself, the collar's calf, it stays put to the bit)
        fraction = parts[rows] / total[rows, None]
        out[np.ix_(rows, cols)] = out[rows, up][:, None] * fraction
    return out


def articulated_pieces(weights: np.ndarray, min_size: int = 3) -> list:
    """The rigid pieces of an articulated part: for each joint, the rows of
    ``weights`` (P, J) wholly on it (``PIECE_WEIGHT``), if at least
    ``min_size``; hinge rows belong to no piece. A list of index arrays."""
    w = np.asarray(weights, dtype=np.float64)
    j = np.argmax(w, axis=1)
    whole = w[np.arange(len(w)), j] >= PIECE_WEIGHT
    return [np.flatnonzero(whole & (j == c)) for c in np.unique(j[whole])
            if int(np.sum(whole & (j == c))) >= min_size]


def group_band(mesh: tuple | None, gv: np.ndarray):
    """The edges of ``mesh`` ((M, 3) points, (E, 2) edges, both indexing
    the rows ``gv`` are among) with both ends in ``gv``, renumbered to
    positions in ``gv``, and their lengths: the ``band`` of
    :func:`articulated_weights`. None without ``mesh``."""
    if mesh is None:
        return None
    points, edges = mesh
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    local = np.full(len(points), -1, dtype=np.int64)
    local[gv] = np.arange(len(gv))
    e = local[edges[(local[edges] >= 0).all(axis=1)]]
    p = np.asarray(points, dtype=np.float64)[gv]
    return e, np.linalg.norm(p[e[:, 1]] - p[e[:, 0]], axis=1)


def item_mesh(items: list) -> tuple:
    """The stacked (M, 3) points and (E, 2) edges of ``items`` (meshes with
    ``points`` and ``faces``), in their order: the ``mesh`` of
    :func:`item_skin_weights`."""
    offsets = np.cumsum([0] + [len(m.points) for m in items])
    points = np.concatenate([np.asarray(m.points, dtype=np.float64) for m in items]) if items else np.zeros((0, 3))
    e = [mesh_edges(np.asarray(m.faces)) + o for m, o in zip(items, offsets[:-1])]
    return points, (np.concatenate(e) if e else np.zeros((0, 2), dtype=np.int64))


def rigid_group_weights(dense: np.ndarray, group: tuple, body_w: sp.csr_matrix,
                        parents: np.ndarray | None = None, mesh: tuple | None = None) -> np.ndarray:
    """The weights of one rigid group's vertices (P, J) from ``dense`` (the
    items' weights of the skin under them, rows of the group's vertices
    read): articulated when ``parents`` is given
    (:func:`articulated_weights`, its hinges spread over ``HINGE_BAND`` of
    the group's surface when ``mesh``, (points, edges) indexing the rows of
    ``dense``, is given); else on one joint when its body patch follows one
    joint (``ONE_JOINT_SHARE``), else unchanged."""
    gv, bv, bw = group
    gv = np.asarray(gv, dtype=np.int64)
    if parents is not None:
        # a hat or glasses come out on the head alone (the skin under them
        # has no other piece's share over the hinge's start); short hair's
        # nape rides the neck (on the head alone the neck came through it:
        # 8.0 % new penetrations in the DAZ walk, 0 % articulated)
        return articulated_weights(dense[gv], parents, band=group_band(mesh, gv))
    bw = np.asarray(bw, dtype=np.float64)
    common = (bw / bw.sum()) @ body_w[np.asarray(bv, dtype=np.int64)].toarray()  # (J,)
    j = int(np.argmax(common))
    if common[j] >= ONE_JOINT_SHARE:
        # the patch follows one joint (a hat on the head, glasses): the
        # whole group on that joint alone moves rigidly
        out = np.zeros((len(gv), dense.shape[1]))
        out[:, j] = 1.0
        return out
    return dense[gv]


def item_skin_weights(binding: Binding, body_joint_indices: np.ndarray, body_joint_weights: np.ndarray,
                      n_joints: int, rigid_groups: list | None = None,
                      max_influences: int = MAX_INFLUENCES, parents: np.ndarray | None = None,
                      mesh: tuple | None = None, skirt: tuple | None = None):
    """Skin weights of every bound item vertex.

    Parameters
    ----------
    binding : Binding
        The items' binding (M vertices) to a body of N vertices.
    body_joint_indices, body_joint_weights : (N, K) arrays
        The body's influences, on the binding's body topology.
    n_joints : int
        Joints of the skeleton the body weights index.
    rigid_groups : list of (item vertex indices (P,), body vertex indices (Q,),
        body vertex weights (Q,)), optional
        Rigid parts (:class:`plan.DressPlan.rigid_groups`), weighted by
        :func:`rigid_group_weights`: articulated when ``parents`` is given,
        else on one joint when the body patch follows one joint.
    max_influences : int
        Influences kept per vertex (default 8).
    parents : (J,) int array, optional
        The skeleton's parents: rigid parts become articulated rigid pieces
        (:func:`articulated_weights`).
    mesh : ((M, 3) points, (E, 2) edges), optional
        The bound items' points and edges (:func:`item_mesh`): articulated
        parts then bend over ``HINGE_BAND`` of their surface.
    skirt : ((M,) bool rows, skirt_weights.Hips, skirt_weights.LegSkin), optional
        The skirt parts' rows (:meth:`plan.DressPlan.skirt_mask`): each side
        the skin of the torso and leg on its side (:func:`skirt_weights.skirt_weights`;
        needs ``mesh``).

    Returns
    -------
    (M, I) int64 joint indices and (M, I) float64 weights, rows summing to 1,
    I = min(max_influences, n_joints).
    """
    body_w = weight_matrix(body_joint_indices, body_joint_weights, n_joints)
    dense = (binding_coefficients(binding, body_w.shape[0], power=BLEND_POWER) @ body_w).toarray()
    groups = [g for g in rigid_groups or [] if len(g[0])]
    # articulated parts read each piece's share in the plain blend (their
    # hinges and bands were measured so); without parents a part not on one
    # joint keeps the skin under it as the rest does
    skin = (binding_coefficients(binding, body_w.shape[0]) @ body_w).toarray() \
        if groups and parents is not None else dense
    for group in groups:
        dense[np.asarray(group[0], dtype=np.int64)] = rigid_group_weights(skin, group, body_w, parents, mesh)
    if skirt is not None and mesh is not None and skirt[0].any():
        rows, axes, leg_skin = skirt
        at = np.asarray(mesh[0])[rows]
        dense[rows] = skirt_weights(dense[rows], at, axes, *leg_skin.weights(at))
    return prune(dense, max_influences)


def transfer_weights(body_points: np.ndarray, body_faces: np.ndarray,
                     body_joint_indices: np.ndarray, body_joint_weights: np.ndarray,
                     item_points: np.ndarray, n_joints: int, max_influences: int = 4,
                     query: SurfaceQuery | None = None):
    """Skin weights for (M, 3) ``item_points`` from a skinned body.

    body_points (N, 3), body_faces (T, 3), body influences (N, K) indices and
    weights into a skeleton of ``n_joints`` joints. Returns (M, max_influences)
    joint indices and weights (rows sum to 1).
    """
    q = query if query is not None else SurfaceQuery(body_faces, body_points)
    res = q.closest(item_points)
    tri = np.asarray(body_faces)[res["triangle"]]  # (M, 3)
    bary = np.clip(res["bary"], 0.0, 1.0)
    bary /= bary.sum(axis=1, keepdims=True)
    m = len(item_points)
    dense = np.zeros((m, n_joints))
    rows = np.repeat(np.arange(m), body_joint_indices.shape[1])
    for c in range(3):
        v = tri[:, c]
        np.add.at(dense, (rows, body_joint_indices[v].ravel()),
                  (body_joint_weights[v] * bary[:, c:c + 1]).ravel())
    k = min(max_influences, n_joints)
    idx = np.argsort(-dense, axis=1)[:, :k]
    w = np.take_along_axis(dense, idx, axis=1)
    w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-12)
    return idx.astype(np.int64), w


def target_body_weights(target_body, fitted_points: np.ndarray, fitted_faces: np.ndarray, n_joints: int,
                        max_influences: int = MAX_INFLUENCES):
    """The target body's skin weights on the fitted reference body (the body
    topology a dressing plan's binding indexes): the target's own when the
    topology is the same (the fit's fast path), else copied from the closest
    target surface point (:func:`transfer_weights`).

    Returns (N_ref, I) joint indices and weights.
    """
    if same_topology(target_body.points, target_body.faces, fitted_points, fitted_faces):
        return target_body.joint_indices, target_body.joint_weights
    return transfer_weights(target_body.points, target_body.faces, target_body.joint_indices,
                            target_body.joint_weights, fitted_points, n_joints, max_influences=max_influences)


def skinned_items(result, target, suffix: str = "", max_influences: int = MAX_INFLUENCES) -> list:
    """The items of a dressing skinned to the target's skeleton.

    Parameters
    ----------
    result : dress.apply.DressResult
        Items dressed on ``target``'s body in its bind pose; its plan's
        binding and rigid groups give the weights, its ``body_points`` (the
        fitted reference body) the body they are read on.
    target : model.Character
        The rigged target (skeleton and skinned body).
    suffix : str
        Appended to each item's name (e.g. ``"_skinned"`` beside point copies).

    Returns
    -------
    list of model.Mesh
        The dressed items with (M_i, I) ``joint_indices``/``joint_weights``
        into ``target.skeleton``'s joints, points in the bind pose.
    """
    if target.skeleton is None or target.body.joint_indices is None:
        raise ValueError(f"{target.source}: the target has no skinned body to skin the items to")
    pl = result.plan
    n_joints = target.skeleton.n_joints
    body_ji, body_jw = target_body_weights(target.body, result.body_points, pl.binding.faces, n_joints,
                                           max_influences)
    # released groups too: freed for the static fit (the shoe did not fit
    # this body rigidly), they are still rigid pieces in motion
    ji, jw = item_skin_weights(pl.binding, body_ji, body_jw, n_joints, pl.rigid_groups + pl.released_groups,
                               max_influences, parents=target.skeleton.parents, mesh=item_mesh(result.items),
                               skirt=_skirt(result, target, body_ji, body_jw))
    out = []
    for item, sl in zip(result.items, pl.item_slices()):
        m = item.copy_with_points(item.points)
        m.name = f"{item.name}{suffix}"
        m.joint_indices, m.joint_weights = ji[sl], jw[sl]
        out.append(m)
    return out


def _skirt(result, target, body_ji: np.ndarray, body_jw: np.ndarray) -> tuple | None:
    """The skirt parts of a dressing and what :func:`skirt_weights.skirt_weights`
    needs for them on the target, or None (no skirt parts, no two legs in the
    skeleton or no skin on them: the skirt then keeps its binding's weights)."""
    rows = result.plan.skirt_mask(parts=True)
    if not rows.any():
        return None
    axes = hip_axes(target.skeleton)
    if axes is None:
        return None
    labels = np.argmax(weight_region_shares(body_ji, body_jw, target.skeleton), axis=1)
    if not has_leg_skin(labels):
        return None
    body_w = weight_matrix(body_ji, body_jw, target.skeleton.n_joints)
    return rows, axes, LegSkin(result.body_points, result.plan.binding.faces, body_w, labels)


def rigid_pieces(result, target) -> list:
    """The articulated rigid pieces of a dressing's rigid parts, per item.

    Each rigid group of ``result.plan`` (a shoe, a hat; released groups
    too) is weighted as :func:`skinned_items` weights it
    (:func:`articulated_weights` with the target skeleton's parents and the
    group's hinge band) and split into its pieces
    (:func:`articulated_pieces`: a shoe's sole and toe cap; a hat whole).
    ``result`` and ``target`` as for :func:`skinned_items`.

    Returns
    -------
    list (one per item) of lists of (P_k,) int64 item vertex indices.
    """
    pl = result.plan
    n_joints = target.skeleton.n_joints
    body_ji, body_jw = target_body_weights(target.body, result.body_points, pl.binding.faces, n_joints)
    body_w = weight_matrix(body_ji, body_jw, n_joints)
    coef = binding_coefficients(pl.binding, body_w.shape[0])
    slices = pl.item_slices()
    points, edges = item_mesh(result.items)
    out = [[] for _ in slices]
    for gv, _, _ in pl.rigid_groups + pl.released_groups:
        gv = np.asarray(gv, dtype=np.int64)
        if len(gv) == 0:
            continue
        owner = [i for i, sl in enumerate(slices) if sl.start <= gv.min() and gv.max() < sl.stop]
        if not owner:
            continue
        # rigid_group_weights' articulated case, on the group's rows alone
        w = articulated_weights((coef[gv] @ body_w).toarray(), target.skeleton.parents,
                                band=group_band((points, edges), gv))
        sl = slices[owner[0]]
        out[owner[0]] += [gv[p] - sl.start for p in articulated_pieces(w)]
    return out
