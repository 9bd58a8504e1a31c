"""Body fitting: deform the reference body mesh onto any target body.

No landmarks, no user input. Steps (all on numpy arrays, internal space:
Y up, metres):

1. **Pose alignment** (:mod:`wearfit_usd.fit.pose_align`): reference joints are
   paired with target joints; the reference body is skinned with its own
   weights so that every mapped joint sits on its target joint and every
   bone points (and reaches) along the target bone. Without a target
   skeleton a global similarity (PCA + scaled ICP) is used instead.
2. **Same topology** (same vertex count, identical triangles): the vertex
   order is the correspondence, the fit is the target's points (fast path).
3. **Non-rigid registration** in the style of Sumner & Popovic 2004
   (vertex formulation): unknowns are the deformed vertices plus one extra
   vertex per triangle along its normal; the energy sums
   ``w_s`` * smoothness (neighbouring triangles' affine maps alike),
   ``w_i`` * identity (maps close to the posed shape) and ``w_c`` *
   closest valid points (both directions: reference -> target surface and
   target -> reference surface; normals compatible; distance threshold),
   solved as sparse normal equations with a rising ``w_c`` schedule. The
   normal matrix is constant inside a level (correspondences only change the
   right-hand side: vertices without a valid match are pulled to where they
   are), so each level costs one numeric Cholesky factorisation re-using one
   symbolic analysis (CHOLMOD, or scipy ``splu`` as fallback), then cheap
   back-substitutions.
4. Pocket collapse (:mod:`wearfit_usd.fit.pockets`): vertices still far
   from the target - pockets the target does not have, such as the mouth
   bag, eye sockets and toe gaps closed by a voxel remesh - are pulled onto
   it in line-searched steps that never turn a triangle over.
5. A final projection onto the target surface that never flips a triangle
   (the collapsed pockets excluded).

Public API: :func:`fit_body` (arrays) and :func:`fit_character`
(:class:`~wearfit_usd.model.Character` pair). The closest-point index and
the quality figures (:class:`~.measures.SurfaceIndex`,
:func:`~.measures.chamfer`, :func:`~.measures.count_flipped`) live in
:mod:`wearfit_usd.fit.measures`.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, fields

import numpy as np
import scipy.sparse as sp

from ..errors import GeometryError
from ..geometry.closest import vertex_normals
from ..geometry.mesh import nondegenerate, same_topology
from ..geometry.sparse_solve import SPDSolver
from ..motion.rig_match import require_match
from ..motion.skinning import skin_points
from ..transforms import rotation_part
from ..types import Faces, JointIndices, Mask, Points, Weights
from . import pose_align as pa
from .measures import SurfaceIndex, chamfer, count_flipped, surface_samples, triangle_normals
from .pockets import collapse_pockets

# --------------------------------------------------------------------------
# options and result


@dataclass
class FitOptions:
    """Knobs of :func:`fit_body` (defaults tuned on the MakeHuman bodies).

    Distances are fractions of the reference body's height unless noted.
    ``levels``: (w_c, distance threshold) per level of the rising schedule;
    ``iterations_per_level`` correspondence updates inside each level.
    """
    pose_align: bool = True            # skeleton-driven posing (step 1)
    stretch_bones: bool = True         # stretch limbs to the target bone lengths
    refine_ends: bool = True           # turn feet, hands, heads onto the target's (needs its weights)
    scale_ends: bool = True            # ... and stretch them where the target's are another size
    prune_leaves: bool = True          # unpair end joints whose bone is < 0.7 or > 1.4 x the
                                       # reference's (a toe joint under the ankle)
    same_topology_shortcut: bool = True
    w_smooth: float = 1.0
    w_identity: float = 0.01
    levels: tuple = ((0.02, 0.06), (0.1, 0.04), (0.5, 0.025), (2.5, 0.015), (12.0, 0.01))
    iterations_per_level: int = 2
    backward_weight: float = 1.0       # target -> reference correspondences
    backward_samples: int = -1         # area-uniform target samples added to its vertices
                                       # (-1: up to the reference's vertex count)
    backward_reach: float = 3.0        # backward distance threshold (x the level's)
    unmatched_weight: float = 1e-3     # pull of unmatched vertices to their place (x w_c)
    normal_angle_deg: float = 60.0     # max angle between matched normals
    near_any_normal: float = 0.0       # matches closer than this (x height) ignore normals
    repair_rounds: int = 3             # flip repair passes after the schedule
    repair_rings: int = 4              # vertex rings freed around a flipped triangle
    collapse_iterations: int = 6       # pocket collapse steps after the repair (0: off)
    collapse_distance: float = 0.2     # farther than this (x mean edge length) starts a pocket
    collapse_step: float = 0.7         # fraction of the way to the closest point per step
    collapse_rings: int = 2            # vertex rings around them solved with them
    final_projection: bool = True
    projection_min: float = 0.001      # final snap: vertices farther than this (x height)
    projection_distance: float = 0.03  # ... and nearer than this snap onto the target
    candidates: int = 4                # nearest triangles tested per closest-point query
    solver: str = "auto"               # "auto", "cholmod" or "splu"
    ref_label: str = "<reference>"     # names used in error messages
    target_label: str = "<target>"

    @classmethod
    def from_any(cls, options) -> FitOptions:
        if options is None:
            return cls()
        if isinstance(options, cls):
            return options
        if isinstance(options, dict):
            known = {f.name for f in fields(cls)}
            bad = set(options) - known
            if bad:
                raise ValueError(f"unknown fit options {sorted(bad)}; known: {sorted(known)}")
            return cls(**options)
        raise TypeError(f"options must be FitOptions, dict or None, not {type(options).__name__}")


@dataclass
class FitResult:
    """Result of :func:`fit_body`.

    points: (N_ref, 3) fitted reference vertices (internal space, metres).
    same_topology: True when the fast path (vertex order = correspondence) ran.
    posed_points: (N_ref, 3) reference after pose/similarity alignment, before
        the non-rigid step.
    diagnostics: timings per stage (s), iterations, chamfer mean/p99 in mm in
        both directions, flipped triangle count, solver, cleaning report.
    warnings: human-readable warnings (also emitted through progress.warn by
        the CLI).
    joint_world: (J_ref, 4, 4) posed reference joint transforms (orthonormal,
        internal) - the fitted body's new bind pose - or None without
        skeletons.
    joint_pairs: [(ref joint, target joint)] used for the pose step.
    """
    points: np.ndarray
    same_topology: bool
    posed_points: np.ndarray
    diagnostics: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    joint_world: np.ndarray | None = None
    joint_pairs: list = field(default_factory=list)


def check_geometry(points: Points, faces: Faces, label: str, what: str) -> Mask:
    """Raise GeometryError naming ``label`` for NaN/inf points or bad faces;
    return (T,) mask of non-degenerate triangles (:func:`~wearfit_usd.geometry.mesh.nondegenerate`)."""
    points = np.asarray(points)
    faces = np.asarray(faces)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise GeometryError(label, f"{what} points must be a non-empty (N, 3) array, got shape "
                                   f"{points.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise GeometryError(label, f"{what} faces must be a non-empty (T, 3) array, got shape "
                                   f"{faces.shape}")
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise GeometryError(label, f"{what} mesh has {int(bad.sum())} NaN/inf points "
                                   f"(first at index {int(np.argmax(bad))})")
    if faces.min() < 0 or faces.max() >= len(points):
        raise GeometryError(label, f"{what} mesh has face vertex indices out of range")
    good = nondegenerate(points, faces)
    if good.sum() == 0:
        raise GeometryError(label, f"{what} mesh has only zero-area triangles")
    return good


# --------------------------------------------------------------------------
# deformation-transfer registration

class _Deformation:
    """Sparse operators of the vertex-formulation energy for one source shape.

    Unknowns: N mesh vertices + one normal vertex per valid triangle.
    ``G`` (3T, n) gives the rows of each triangle's affine map Q^T (per
    coordinate); ``L`` = w_s Gs^T Gs + w_i G^T G, ``b_id`` = w_i G^T I.
    """

    def __init__(self, points: np.ndarray, faces: np.ndarray, valid: np.ndarray,
                 w_smooth: float, w_identity: float):
        self.n_points = len(points)
        f = faces[valid]
        self.faces = f
        t = len(f)
        self.n = self.n_points + t
        v1, v2, v3 = points[f[:, 0]], points[f[:, 1]], points[f[:, 2]]
        cr = np.cross(v2 - v1, v3 - v1)
        e3 = cr / np.sqrt(np.linalg.norm(cr, axis=1))[:, None]
        self.normal_offset = e3  # v4 - v1 in the source shape
        E = np.stack([v2 - v1, v3 - v1, e3], axis=1)  # rows = edges
        Einv = np.linalg.inv(E)  # (T, 3, 3): Q^T = Einv @ E'
        rows = np.repeat(np.arange(3 * t), 4)
        tt = np.repeat(np.arange(t), 3)
        cols = np.stack([f[tt, 0], f[tt, 1], f[tt, 2], self.n_points + tt], axis=1).ravel()
        ei = Einv.reshape(3 * t, 3)
        vals = np.concatenate([-ei.sum(axis=1, keepdims=True), ei], axis=1).ravel()
        G = sp.csr_matrix((vals, (rows, cols)), shape=(3 * t, self.n))
        # triangle pairs sharing an edge
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        e.sort(axis=1)
        key = e[:, 0].astype(np.int64) * self.n_points + e[:, 1]
        order = np.argsort(key, kind="stable")
        ks = key[order]
        same = np.flatnonzero(ks[1:] == ks[:-1])
        tri_of_edge = np.tile(np.arange(t), 3)
        ta, tb = tri_of_edge[order[same]], tri_of_edge[order[same + 1]]
        p = len(ta)
        r = np.arange(3 * p)
        ra = (3 * np.repeat(ta, 3) + np.tile(np.arange(3), p))
        rb = (3 * np.repeat(tb, 3) + np.tile(np.arange(3), p))
        Dp = sp.csr_matrix((np.concatenate([np.ones(3 * p), -np.ones(3 * p)]),
                            (np.concatenate([r, r]), np.concatenate([ra, rb]))),
                           shape=(3 * p, 3 * t))
        Gs = Dp @ G
        self.n_pairs = p
        ident = np.zeros((3 * t, 3))
        ident[np.arange(3 * t), np.tile(np.arange(3), t)] = 1.0
        L = w_smooth * (Gs.T @ Gs) + w_identity * (G.T @ G)
        # every mesh vertex later gets a positive diagonal (correspondence
        # weight), so the pattern is the same at every level
        self.L = sp.csc_matrix(L)
        self.L.sort_indices()
        self.b_id = w_identity * (G.T @ ident)
        self.G = G

    def initial(self, points: np.ndarray) -> np.ndarray:
        v1 = points[self.faces[:, 0]]
        return np.concatenate([points, v1 + self.normal_offset])

    def system(self, w_c: np.ndarray) -> sp.csc_matrix:
        d = np.zeros(self.n)
        d[:self.n_points] = w_c
        A = self.L + sp.diags(d, format="csc")
        A = sp.csc_matrix(A)
        A.sort_indices()
        return A


def _correspondence_targets(x: np.ndarray, faces: np.ndarray, target: SurfaceIndex,
                            target_points: np.ndarray, target_normals: np.ndarray,
                            max_dist: float, cos_normal: float, backward_weight: float,
                            k: int, near_any: float = 0.0, frozen: np.ndarray | None = None,
                            target_weights: np.ndarray | None = None,
                            backward_dist: float | None = None):
    """Per source vertex, where the closest-point terms pull it.

    Forward: each vertex to its closest target surface point (valid when
    within ``max_dist`` and normals agree). Backward: each target vertex to
    its closest point on the current source surface; its pull is spread on
    that triangle's vertices by barycentric weight. Returns (goal (N, 3),
    weight (N,) of the pull, n_forward_valid, n_backward_valid).
    """
    n = len(x)
    vn = vertex_normals(x, faces)
    fw = target.query(x, fast=True)
    cos_f = np.einsum("ij,ij->i", vn, fw["normal"])
    ok_f = (fw["distance"] < max_dist) & ((cos_f > cos_normal) | (fw["distance"] < near_any))
    if frozen is not None:
        ok_f &= ~frozen
    wf = ok_f.astype(float)
    num = (fw["points"] - x) * wf[:, None]
    den = wf.copy()
    nb = 0
    if backward_weight > 0:
        src = SurfaceIndex(x, faces, k=k)
        bw = src.query(target_points, fast=True)
        bdist = max_dist if backward_dist is None else backward_dist
        ok_b = (bw["distance"] < bdist) & (np.einsum("ij,ij->i", target_normals, bw["normal"])
                                            > cos_normal)
        if frozen is not None:
            ok_b &= ~frozen[src.faces[bw["face_local"]]].any(axis=1)
        nb = int(ok_b.sum())
        scale = backward_weight * n / max(len(target_points), 1)
        disp = (target_points - bw["points"])[ok_b]
        fv = src.faces[bw["face_local"][ok_b]]  # (M, 3) source vertices
        bb = bw["bary"][ok_b] * scale
        if target_weights is not None:
            bb = bb * target_weights[ok_b, None]
        idx = fv.ravel()
        wts = bb.ravel()
        den += np.bincount(idx, wts, minlength=n)
        for c in range(3):
            num[:, c] += np.bincount(idx, (bb * disp[:, c][:, None]).ravel(), minlength=n)
    has = den > 1e-12
    goal = x.copy()
    goal[has] += num[has] / den[has, None]
    return goal, has, int(ok_f.sum()), nb


def _backward_set(tgt: SurfaceIndex, count: int):
    """The target points of the backward (target -> fit) term: the target's
    vertices plus ``count`` area-uniform samples of its surface, so that a
    low-poly target (a box head: 8 corners) pulls over its whole area.

    Returns points (M, 3), unit normals (M, 3) and weights (M,) (mean 1):
    each vertex weighs a third of its triangles' area, each sample an equal
    share of the area; the two halves weigh the same in total.
    """
    area = 0.5 * np.linalg.norm(triangle_normals(tgt.points, tgt.faces), axis=1)
    va = np.bincount(tgt.faces.ravel(), np.repeat(area / 3.0, 3), minlength=len(tgt.points))
    s = surface_samples(tgt.points, tgt.faces, count)
    sn = tgt.query(s)["normal"]
    w = np.concatenate([va / max(va.sum(), 1e-30), np.full(count, 1.0 / count)])
    w *= len(w) / w.sum()
    return np.concatenate([tgt.points, s]), np.concatenate([tgt.vertex_normals, sn]), w


def _register(src_points, src_faces, valid, target: SurfaceIndex, opts: FitOptions,
              height: float, diag: dict):
    """Non-rigid registration of (src_points, src_faces) onto ``target``.

    Returns (fitted points (N, 3), pocket (N,) bool: the vertices the pocket
    collapse solved for)."""
    t0 = time.perf_counter()
    centre = src_points.mean(axis=0)
    e = src_points[src_faces[valid][:, [0, 1, 2]]]
    h = float(np.mean(np.linalg.norm(e[:, 1] - e[:, 0], axis=1)))  # unit length
    P = (src_points - centre) / h
    TP = (target.points - centre) / h
    tgt = SurfaceIndex(TP, target.faces, k=opts.candidates)
    tgt_normals = tgt.vertex_normals
    BP, b_normals, b_weights = TP, tgt_normals, None
    n_samples = opts.backward_samples
    if n_samples < 0:  # a target sparser than the reference: top up its vertices
        n_samples = max(0, len(P) - len(TP))
    diag["backward_samples"] = int(n_samples)
    if n_samples > 0:
        BP, b_normals, b_weights = _backward_set(tgt, n_samples)
    deform = _Deformation(P, src_faces, valid, opts.w_smooth, opts.w_identity)
    solver = SPDSolver(opts.solver)
    diag["solver"] = solver.name
    diag["unknowns"] = deform.n
    diag["time_setup_s"] = time.perf_counter() - t0
    x = deform.initial(P)
    faces_valid = src_faces[valid]
    cos_n = float(np.cos(np.radians(opts.normal_angle_deg)))
    n = len(P)
    t_factor = t_corr = t_solve = 0.0
    iters = 0
    for w_c, dist in opts.levels:
        for it in range(opts.iterations_per_level):
            tc = time.perf_counter()
            goal, has, nf, nb = _correspondence_targets(
                x[:n], faces_valid, tgt, BP, b_normals, dist * height / h, cos_n,
                opts.backward_weight, opts.candidates, near_any=opts.near_any_normal * height / h,
                target_weights=b_weights, backward_dist=opts.backward_reach * dist * height / h)
            t_corr += time.perf_counter() - tc
            if it == 0:
                # weights fixed for the level: matched vertices w_c, the others
                # a weak pull to where they are (they follow their neighbours)
                tf = time.perf_counter()
                wv = np.where(has, w_c, w_c * opts.unmatched_weight)
                solver.factor(deform.system(wv))
                t_factor += time.perf_counter() - tf
            ts = time.perf_counter()
            rhs = deform.b_id.copy()
            rhs[:n] += wv[:, None] * goal
            x = solver.solve(rhs)
            t_solve += time.perf_counter() - ts
            iters += 1
    # flip repair: vertices around triangles that turned over lose their
    # closest-point pull and follow the smooth deformation of their
    # surroundings (mouth or toe crevices the target does not have)
    repaired = 0
    free = np.zeros(n, bool)
    n0 = triangle_normals(P, faces_valid)
    for _ in range(opts.repair_rounds):
        flip = np.einsum("ij,ij->i", n0, triangle_normals(x[:n], faces_valid)) <= 0
        if not flip.any():
            break
        repaired += int(flip.sum())
        grow = np.zeros(n, bool)
        grow[faces_valid[flip].ravel()] = True
        for _ in range(opts.repair_rings):
            grow[faces_valid[grow[faces_valid].any(axis=1)].ravel()] = True
        free |= grow
        tc = time.perf_counter()
        goal, has, nf, nb = _correspondence_targets(
            x[:n], faces_valid, tgt, BP, b_normals, dist * height / h, cos_n,
            opts.backward_weight, opts.candidates, near_any=opts.near_any_normal * height / h,
            frozen=free, target_weights=b_weights, backward_dist=opts.backward_reach * dist * height / h)
        t_corr += time.perf_counter() - tc
        tf = time.perf_counter()
        wv = np.where(has & ~free, w_c, np.where(free, w_c * 1e-6, w_c * opts.unmatched_weight))
        solver.factor(deform.system(wv))
        t_factor += time.perf_counter() - tf
        for _ in range(2):
            rhs = deform.b_id.copy()
            rhs[:n] += wv[:, None] * np.where(free[:, None], x[:n], goal)
            x = solver.solve(rhs)
            iters += 1
    # pockets the target does not have (mouth, eye sockets, toe gaps closed
    # by a remesh): pulled in by line-searched steps that turn no triangle over
    tp = time.perf_counter()

    def closest(q):
        r = tgt.query(q, fast=True)
        return r["points"], r["distance"]

    x, pocket, cinfo = collapse_pockets(x, n, faces_valid, n0, deform.L, closest,
                                weight=w_c, min_distance=opts.collapse_distance,
                                step=opts.collapse_step, iterations=opts.collapse_iterations,
                                grow_rings=opts.collapse_rings, solver=opts.solver)
    diag.update(time_factor_s=t_factor, time_correspondence_s=t_corr, time_solve_s=t_solve,
                iterations=iters, factorizations=solver.n_factorizations,
                forward_valid_last=nf, backward_valid_last=nb, repaired_flips=repaired,
                freed_vertices=int(free.sum()), collapse_region_vertices=cinfo["region"],
                collapse_steps=cinfo["steps"], collapse_solves=cinfo["solves"],
                collapse_held_vertices=cinfo["held"],
                time_collapse_s=time.perf_counter() - tp)
    return x[:n] * h + centre, pocket


def _project(points, faces, target: SurfaceIndex, reference_normals: np.ndarray,
             min_dist: float, max_dist: float, max_rounds: int = 50,
             keep: np.ndarray | None = None):
    """Snap vertices lying between ``min_dist`` and ``max_dist`` from the target
    onto their closest target point, then undo the move of every vertex of
    a triangle that would turn over relative to ``reference_normals``
    (T, 3), until no triangle does. Vertices already within ``min_dist``
    stay (they sit slightly outside on convex parts, which keeps chords
    close to the target); ``keep`` (N,) bool vertices stay too (the pocket
    collapse placed them: snapping some of a folded pocket's vertices and
    not others stretches triangles across it)."""
    q = target.query(points)
    ok = (q["distance"] > min_dist) & (q["distance"] < max_dist)
    if keep is not None:
        ok &= ~keep
    out = points
    for _ in range(max_rounds):
        out = np.where(ok[:, None], q["points"], points)
        flip = np.einsum("ij,ij->i", reference_normals, triangle_normals(out, faces)) <= 0
        if not flip.any():
            break
        ok[faces[flip].ravel()] = False
    else:
        out = points
        ok[:] = False
    return out, int(ok.sum())


# --------------------------------------------------------------------------
# public API

def fit_body(ref_points: Points, ref_faces: Faces, target_points: Points, target_faces: Faces, *,
             ref_skeleton=None, ref_joint_indices: JointIndices | None = None,
             ref_joint_weights: Weights | None = None, target_skeleton=None,
             options=None, target_joint_indices: JointIndices | None = None,
             target_joint_weights: Weights | None = None) -> FitResult:
    """Deform the reference body onto the target body.

    ref_points (N, 3), ref_faces (T, 3), target_points (M, 3), target_faces
    (S, 3): internal space (Y up, metres), triangles. ref_skeleton /
    target_skeleton: :class:`~wearfit_usd.model.Skeleton` (bind pose of the
    meshes); ref_joint_indices / ref_joint_weights (N, K): the reference
    body's skin influences (needed for the pose step). options:
    :class:`FitOptions` or a dict of its fields.

    Returns :class:`FitResult` (``points`` (N, 3) keep the reference
    topology). Raises :class:`~wearfit_usd.errors.GeometryError` for NaN/inf
    points, out-of-range faces or meshes without any non-degenerate triangle.
    """
    opts = FitOptions.from_any(options)
    t_start = time.perf_counter()
    ref_points = np.asarray(ref_points, dtype=np.float64)
    target_points = np.asarray(target_points, dtype=np.float64)
    ref_faces = np.asarray(ref_faces, dtype=np.int64)
    target_faces = np.asarray(target_faces, dtype=np.int64)
    ref_valid = check_geometry(ref_points, ref_faces, opts.ref_label, "reference")
    tgt_valid = check_geometry(target_points, target_faces, opts.target_label, "target")
    warnings_: list[str] = []
    diag: dict = {"ref_vertices": len(ref_points), "target_vertices": len(target_points),
                  "ref_degenerate_triangles": int((~ref_valid).sum()),
                  "target_degenerate_triangles": int((~tgt_valid).sum())}
    if diag["ref_degenerate_triangles"] or diag["target_degenerate_triangles"]:
        warnings_.append(f"ignored {diag['ref_degenerate_triangles']} zero-area reference and "
                         f"{diag['target_degenerate_triangles']} zero-area target triangles")
    # ---- step 1: pose / similarity alignment
    t0 = time.perf_counter()
    joint_world = None
    pairs: list = []
    have_rigs = ref_skeleton is not None and target_skeleton is not None
    can_skin = have_rigs and ref_joint_indices is not None and ref_joint_weights is not None
    if have_rigs:
        match = pa.skeleton_match(ref_skeleton, target_skeleton)
        if opts.pose_align:
            require_match(match, opts.ref_label, opts.target_label, "the pose step",
                          "use --no-pose for similarity alignment only")
        pairs = match.index_pairs()
        diag["joint_match"] = {"confidence": round(match.confidence, 3), "by_names": match.by_names,
                               "missing_key_roles": match.missing}
    if have_rigs and opts.pose_align and opts.prune_leaves:
        pairs, dropped = pa.prune_leaf_pairs(ref_skeleton.bind_world, ref_skeleton.parents,
                                             target_skeleton.bind_world, pairs)
        if dropped:
            diag["unpaired_end_joints"] = [ref_skeleton.joint_names[j] for j in dropped]
    if have_rigs and len(pairs) >= 3:
        pose = pa.pose_to_target(ref_skeleton.bind_world, ref_skeleton.parents,
                                 target_skeleton.bind_world, pairs, stretch=opts.stretch_bones)
        if opts.pose_align and can_skin:
            posed = skin_points(ref_points, np.asarray(ref_joint_indices),
                                np.asarray(ref_joint_weights), pose["skin"])
            joint_world = pose["world"]
            if opts.refine_ends and target_joint_weights is not None:
                joint_world, skin, turns = pa.refine_end_segments(
                    posed, np.asarray(ref_joint_indices), np.asarray(ref_joint_weights),
                    joint_world, pose["skin"], ref_skeleton.parents, target_points,
                    np.asarray(target_joint_indices), np.asarray(target_joint_weights),
                    target_skeleton.parents, pairs, target_faces=target_faces[tgt_valid],
                    scale=opts.scale_ends)
                if turns:
                    posed = skin_points(ref_points, np.asarray(ref_joint_indices),
                                        np.asarray(ref_joint_weights), skin)
                    diag["turned_end_segments"] = {ref_skeleton.joint_names[j]: a
                                                   for j, a, _ in turns}
                    scaled = {ref_skeleton.joint_names[j]: list(s) for j, _, s in turns
                              if any(v != 1.0 for v in s)}
                    if scaled:
                        diag["scaled_end_segments"] = scaled

            diag["alignment"] = "pose"
        else:
            if opts.pose_align and not can_skin:
                warnings_.append("reference has no skin weights: pose step skipped, "
                                 "similarity from the joints only")
            posed = pa.apply(pose["similarity"], ref_points)
            sim = pose["similarity"]
            joint_world = ref_skeleton.bind_world.copy()
            joint_world[:, :3, :3] = rotation_part(ref_skeleton.bind_world) @ rotation_part(sim)
            joint_world[:, 3, :3] = pa.apply(sim, ref_skeleton.bind_positions())
            diag["alignment"] = "joint similarity"
        diag["joint_pairs"] = len(pairs)
    else:
        if target_skeleton is None:
            warnings_.append(f"{opts.target_label}: target has no skeleton; aligned by "
                             "similarity (PCA + ICP) only before the non-rigid fit")
        elif ref_skeleton is not None:
            warnings_.append(f"only {len(pairs)} joints map between the rigs; aligned by "
                             "similarity (PCA + ICP)")
        sim, _ = pa.surface_similarity(ref_points, target_points)
        posed = pa.apply(sim, ref_points)
        if ref_skeleton is not None:
            joint_world = ref_skeleton.bind_world.copy()
            joint_world[:, :3, :3] = rotation_part(ref_skeleton.bind_world) @ rotation_part(sim)
            joint_world[:, 3, :3] = pa.apply(sim, ref_skeleton.bind_positions())
        diag["alignment"] = "surface similarity"
        diag["joint_pairs"] = len(pairs)
    diag["time_align_s"] = time.perf_counter() - t0

    same = opts.same_topology_shortcut and same_topology(ref_points, ref_faces, target_points,
                                                          target_faces)
    diag["same_topology"] = bool(same)
    if same:
        fitted = target_points.copy()
        diag.update(time_register_s=0.0, iterations=0, solver="none (same topology)")
    else:
        # ---- step 3: non-rigid registration
        t0 = time.perf_counter()
        height = float(np.ptp(posed, axis=0).max())
        target = SurfaceIndex(target_points, target_faces)
        fitted, pocket = _register(posed, ref_faces, ref_valid, target, opts, height, diag)
        diag["time_register_s"] = time.perf_counter() - t0
        if opts.final_projection:
            t0 = time.perf_counter()
            fitted, n_proj = _project(fitted, ref_faces[ref_valid], target,
                                      triangle_normals(posed, ref_faces[ref_valid]),
                                      opts.projection_min * height,
                                      opts.projection_distance * height, keep=pocket)
            diag["projected_vertices"] = n_proj
            diag["time_project_s"] = time.perf_counter() - t0
        diag["time_total_fit_s"] = time.perf_counter() - t_start
        t0 = time.perf_counter()
        diag.update(chamfer(fitted, ref_faces[ref_valid], target_points, target_faces, target))
        diag["time_metrics_s"] = time.perf_counter() - t0
    diag["flipped_triangles"] = count_flipped(posed, fitted, ref_faces)
    diag.setdefault("time_total_fit_s", time.perf_counter() - t_start)
    if joint_world is not None and ref_joint_weights is not None and pairs:
        joint_world = _move_unmapped_joints(joint_world, pairs, posed, fitted,
                                            np.asarray(ref_joint_indices),
                                            np.asarray(ref_joint_weights))
    return FitResult(points=fitted, same_topology=bool(same), posed_points=posed,
                     diagnostics=diag, warnings=warnings_, joint_world=joint_world,
                     joint_pairs=pairs)


def _move_unmapped_joints(world, pairs, posed, fitted, ji, jw):
    """Unmapped joints follow the skin-weighted mean displacement of the
    vertices they drive (mapped joints already sit on the target joints)."""
    world = world.copy()
    n_j = len(world)
    mapped = np.zeros(n_j, bool)
    mapped[[i for i, _ in pairs]] = True
    disp = fitted - posed
    w_sum = np.bincount(ji.ravel(), jw.ravel(), minlength=n_j)
    for c in range(3):
        d = np.bincount(ji.ravel(), (jw * disp[:, c][:, None]).ravel(), minlength=n_j)
        move = (~mapped) & (w_sum > 1e-9)
        world[move, 3, c] += d[move] / w_sum[move]
    return world


def fit_character(ref, target, options=None) -> FitResult:
    """:func:`fit_body` for two :class:`~wearfit_usd.model.Character` (their
    body meshes, skeletons and the reference's skin weights)."""
    opts = FitOptions.from_any(options)
    if opts.ref_label == "<reference>" or opts.target_label == "<target>":
        d = asdict(opts)
        if opts.ref_label == "<reference>":
            d["ref_label"] = ref.source
        if opts.target_label == "<target>":
            d["target_label"] = target.source
        opts = FitOptions(**d)
    return fit_body(ref.body.points, ref.body.faces, target.body.points, target.body.faces,
                    ref_skeleton=ref.skeleton, ref_joint_indices=ref.body.joint_indices,
                    ref_joint_weights=ref.body.joint_weights, target_skeleton=target.skeleton,
                    options=opts, target_joint_indices=target.body.joint_indices,
                    target_joint_weights=target.body.joint_weights)
