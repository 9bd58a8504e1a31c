"""Skinned copies fitted to example poses: rest points that the skeleton's
linear blend skinning carries onto the per-frame redress.

The skinned copies of the items (:func:`dress.item_weights.skinned_items`,
written by ``dress``/``animate --items skinned|both``) are posed by an
engine's (or UsdSkel's) linear blend skinning with the weights of the skin
under each vertex. Where the body's own skinning pinches (armpits, the chest
under a lowered arm) a tight suit so skinned sinks into the skin: on the CMU
walk the skinned ``female_casualsuit01`` had 1.1-2.6 percentage points more
new penetrations than the per-frame redress on every dev target (issue 19
asks at most 1). The redress pushes those vertices out frame by frame; no
fixed rest point can, but one chosen over many poses comes close.

Maths. A vertex with rest point ``p`` (row vector), influences ``j_i`` and
weights ``w_i`` (kept: fitting them as well over-fitted the example poses,
the suit went 3.6-6.3 % into the body on another clip) is posed in frame ``f``
with the (4, 4) row-vector skinning matrices ``S_f`` by::

    x_f(p) = [p, 1] sum_i w_i S_f[j_i][:, :3] = p R_f + t_f

with ``R_f = sum_i w_i S_f[j_i][:3, :3]`` and ``t_f = sum_i w_i S_f[j_i][3, :3]``.
Given the redress ``y_f`` of the example frames and the static dress
``p_0`` (the bind pose), the rest point solves the least squares::

    min_p  sum_f |p R_f + t_f - y_f|^2  +  mu F |p - p_0|^2
           + kappa sum_(f active) (n_f . (p R_f + t_f) - n_f . c_f - h)^2

``mu`` keeps the rest shape (it is what the bind pose shows); the last sum
is a one-sided clearance term: ``c_f``, ``n_f`` the closest point of the
posed body to the skinned vertex and its normal, ``h = min(clearance_0,
margin)``, a term added for each frame where the skinned vertex lies closer
to the body than ``h`` (the active set grows over ``rounds``; each round
solves all vertices' 3 x 3 systems at once); last, no rest point moves
more than ``max_move`` (what the bind pose may show: a muscular body's
suit asked for up to 17 mm). On body_female_heavy (CMU walk, 60 frames)
the skinned suit's new penetrations were 2.43 % against the redress's
0.58 %; the least squares alone 1.90 %, with the clearance term 1.37 %.

The example poses are the package's own procedural clips (``arm_raise``,
``squat``, ``look``, ``walk``: the arms from the sides to above the head,
a deep squat, the head and chest turning, a walking swing), one after the
other at 5 fps, every frame an example pose (40 poses), dressed by the same
pipeline as the shot (:func:`training_frames`); none of the CMU clips the
benchmarks measure. These are the instants of every 3rd frame at 15 fps;
run at 15 fps the frames between cost a third more time (the example run
2.8-3.0 -> 1.8-2.0 s) for the same fit (the skinned quick benchmark: 18 of
20 pairs within 1 point either way, each row within 0.05 points). Two more
clips (jogging in place with the elbows bent and high knees; the arms
overhead with the elbows bent, crossed in front, swung back in a forward
bend) did not help either: over every CMU clip's first 60 frames on four
female targets, 103 -> 104 of 128 item rows within 1 point.
"""
from __future__ import annotations

import tempfile
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..geometry.closest import SurfaceQuery
from .measures import layer_pairs

#: the package's procedural clips the copies are fitted on
TRAINING_CLIPS = ("arm_raise", "squat", "look", "walk")
#: every n-th output frame of each clip (run at TRAINING_FPS) is an example pose
TRAINING_EVERY = 1
#: the example clips are run at this rate (the bound parts need no finer steps)
TRAINING_FPS = 5.0
#: weight of the rest shape against the example poses (per frame)
REST_WEIGHT = 1.0
#: weight of the one-sided clearance term
CLEARANCE_WEIGHT = 20.0
#: the clearance (m) kept in the example poses: a vertex's static clearance, at most this
CLEARANCE_MARGIN = 0.002
#: rounds of the clearance term's active set
ROUNDS = 4
#: no rest point moves farther than this (m): what the bind pose may show
MAX_MOVE = 0.008
#: an inner layer's vertex moves out at most as far as the one over it, plus this share of their gap
LAYER_SHARE = 0.5


class FrameRecorder:
    """Collects a shot's frames for fitting (``AnimateOptions.frame_sink``).

    ``animate`` calls :meth:`start` once with the (M,) bool mask of the item
    vertices not moved by their binding (cloth-free vertices, items skinned
    whole), then :meth:`add` per output frame with the frame's (J, 4, 4)
    skinning matrices, the skinned body (N, 3) and the items (M, 3) as
    written; every ``every``-th frame is kept."""

    def __init__(self, every: int = TRAINING_EVERY):
        if every < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.every = int(every)
        self.free = None
        self.mats, self.bodies, self.items = [], [], []

    def start(self, free: np.ndarray) -> None:
        self.free = np.asarray(free, dtype=bool).copy()

    def add(self, frame: int, skin_mats: np.ndarray, body: np.ndarray, items: np.ndarray) -> None:
        if frame % self.every:
            return
        self.mats.append(np.array(skin_mats, dtype=np.float64))
        self.bodies.append(np.array(body, dtype=np.float64))
        self.items.append(np.array(items, dtype=np.float64))

    def arrays(self):
        """(F, J, 4, 4) skinning matrices, (F, N, 3) bodies, (F, M, 3) items."""
        if not self.mats:
            raise ValueError("no frames recorded")
        return np.stack(self.mats), np.stack(self.bodies), np.stack(self.items)


def _posed_terms(joint_indices: np.ndarray, joint_weights: np.ndarray, skin_mats: np.ndarray):
    """Per frame and vertex the blended (3, 3) ``R_f`` and (3,) ``t_f``:
    (F, M, 3, 3) and (F, M, 3)."""
    ji = np.asarray(joint_indices, dtype=np.int64)
    jw = np.asarray(joint_weights, dtype=np.float64)
    s = np.asarray(skin_mats, dtype=np.float64)[:, :, :, :3]  # (F, J, 4, 3)
    blended = np.zeros((len(s), len(ji), 4, 3))               # (F, M, 4, 3)
    # one influence column at a time: gathering all of them at once,
    # (F, M, I, 4, 3), was 600 MB for a suit over 40 example poses
    for i in range(ji.shape[1]):
        rows = np.flatnonzero(jw[:, i] > 0.0)
        blended[:, rows] += jw[rows, i, None, None] * s[:, ji[rows, i]]
    return blended[:, :, :3, :], blended[:, :, 3, :]


def fit_rest_points(rest: np.ndarray, joint_indices: np.ndarray, joint_weights: np.ndarray,
                    skin_mats: np.ndarray, targets: np.ndarray, body_faces: np.ndarray | None = None,
                    bodies: np.ndarray | None = None, clearance0: np.ndarray | None = None,
                    rest_weight: float = REST_WEIGHT, clearance_weight: float = CLEARANCE_WEIGHT,
                    margin: float = CLEARANCE_MARGIN, rounds: int = ROUNDS,
                    max_move: float | None = MAX_MOVE) -> np.ndarray:
    """Rest points whose linear blend skinning follows ``targets`` over
    example poses (see the module docstring for the least squares).

    Parameters
    ----------
    rest : (M, 3) the static dress in the bind pose (``p_0``).
    joint_indices, joint_weights : (M, I) influences (kept).
    skin_mats : (F, J, 4, 4) row-vector skinning matrices of the example frames.
    targets : (F, M, 3) the vertices' redress in those frames (``y_f``).
    body_faces : (T, 3) int, bodies : (F, N, 3) the posed body of each frame,
        clearance0 : (M,) the vertices' static clearance (signed, metres):
        the one-sided clearance term; all None: the least squares alone.
    rest_weight, clearance_weight, margin, rounds : ``mu``, ``kappa``, the
        clearance cap (m) and the active-set rounds.
    max_move : a rest point's move from ``rest`` is shortened to this (m);
        None: not limited.

    Returns
    -------
    (M, 3) float64 rest points.
    """
    rest = np.asarray(rest, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    m = len(rest)
    skin_mats = np.asarray(skin_mats, dtype=np.float64)
    f = len(skin_mats)
    if rest.shape != (m, 3) or targets.shape != (f, m, 3):
        raise ValueError(f"rest {rest.shape} and targets {targets.shape} do not match {f} frames of {m} points")
    if np.shape(joint_indices) != np.shape(joint_weights) or len(joint_indices) != m:
        raise ValueError("joint_indices and joint_weights must be (M, I) for the M rest points")
    clearance_term = bodies is not None
    if clearance_term and (body_faces is None or clearance0 is None or len(bodies) != f):
        raise ValueError("the clearance term needs body_faces, one body per frame and clearance0")
    if f == 0 or m == 0:
        return rest.copy()
    R, t = _posed_terms(joint_indices, joint_weights, skin_mats)
    eye = np.eye(3)
    a0 = np.einsum("fmkc,fmlc->mkl", R, R) + rest_weight * f * eye
    b0 = np.einsum("fmkc,fmc->mk", R, targets - t) + rest_weight * f * rest
    p = np.linalg.solve(a0, b0[..., None])[..., 0]
    if not clearance_term or rounds <= 0 or clearance_weight <= 0:
        return _limited(rest, p, max_move)
    want = np.minimum(np.maximum(np.asarray(clearance0, dtype=np.float64), 0.0), margin)
    query = SurfaceQuery(np.asarray(body_faces, dtype=np.int64), np.asarray(bodies[0], dtype=np.float64))
    a_pen = np.zeros_like(a0)
    b_pen = np.zeros_like(b0)
    # each frame's candidate triangles, found once (the KD-trees of 60 posed
    # bodies were three quarters of the time): the rest points move a few
    # millimetres between rounds
    candidates = [None] * f
    # each frame's distances as last measured and the skinned points they
    # were measured at: a vertex outside by more than ``want`` plus how far
    # it has moved since cannot have come within ``want`` (the distance to
    # a fixed set of triangles changes no faster than the point moves), so
    # later rounds measure only the others
    seen = np.full((f, m), -np.inf)
    seen_at = np.zeros((f, m, 3))
    for _ in range(rounds):
        added = 0
        for k in range(f):
            x = np.einsum("mk,mkc->mc", p, R[k]) + t[k]
            query.update(np.asarray(bodies[k], dtype=np.float64))
            if candidates[k] is None:
                _, ci = query.centroid_tree.query(x, k=min(8, len(query.faces)))
                _, vi = query.vertex_tree.query(x, k=1)
                candidates[k] = np.concatenate([np.asarray(ci).reshape(m, -1), query.ring[vi]], axis=1)
            moved = np.linalg.norm(x - seen_at[k], axis=1)
            rows = np.flatnonzero(~(seen[k] - moved > want))  # want >= 0: only vertices outside are skipped
            if not len(rows):
                continue
            c = query.closest(x[rows], candidates=candidates[k][rows], ring=False)
            seen[k, rows], seen_at[k, rows] = c["distance"], x[rows]
            hit = np.flatnonzero(c["distance"] < want[rows])
            if not len(hit):
                continue
            act = rows[hit]
            c = {key: c[key][hit] for key in ("normal", "point")}
            added += len(act)
            n = _unit_rows(c["normal"])  # the closest feature's pseudo-normal
            # n . (p R + t) >= n . c + h, as a least-squares row g . p = rhs
            g = np.einsum("ac,akc->ak", n, R[k][act])
            rhs = (np.einsum("ac,ac->a", n, c["point"]) + want[act]
                   - np.einsum("ac,ac->a", n, t[k][act]))
            a_pen[act] += clearance_weight * g[:, :, None] * g[:, None, :]
            b_pen[act] += clearance_weight * g * rhs[:, None]
        if not added:
            break
        p = np.linalg.solve(a0 + a_pen, (b0 + b_pen)[..., None])[..., 0]
    return _limited(rest, p, max_move)


def _unit_rows(v: np.ndarray) -> np.ndarray:
    """The rows of (M, 3) ``v`` made unit (zero rows stay zero)."""
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)


def _limited(rest: np.ndarray, p: np.ndarray, max_move: float | None) -> np.ndarray:
    """``p`` with each point's move from ``rest`` shortened to ``max_move``."""
    if max_move is None:
        return p
    d = p - rest
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return rest + d * np.minimum(1.0, max_move / np.maximum(n, 1e-300))


def training_motion(clips=TRAINING_CLIPS):
    """The package's procedural ``clips`` (:mod:`demo.samples.motions`, shipped
    as ``wearfit_usd/motions/<clip>.bvh``; one skeleton) one after the other
    as one :class:`io.bvh.BVHMotion`: one shot dresses the example poses
    (the arm raise and the squat start and end standing, arms at the sides,
    as the walk starts)."""
    from ..demo.samples import motion_path
    from ..io.bvh import read_bvh
    motions = [read_bvh(motion_path(c)) for c in clips]
    first = motions[0]
    for m in motions[1:]:
        if m.joint_names != first.joint_names or m.values.shape[1] != first.values.shape[1]:
            raise ValueError(f"{m.path}: not the skeleton of {first.path}")
    values = np.concatenate([m.values for m in motions])
    return replace(first, path="+".join(Path(m.path).stem for m in motions), values=values, n_frames=len(values))


def training_frames(reference, target, ref_plan, options, every: int = TRAINING_EVERY,
                    clips=TRAINING_CLIPS) -> tuple:
    """The example frames: ``reference``'s items on ``target`` through
    :func:`training_motion` at :data:`TRAINING_FPS`, dressed and evaluated
    per frame as ``animate`` does with ``options`` (an
    :class:`try_on.AnimateOptions`; its clip range, items and measures are
    replaced); ``ref_plan`` the reference's dressing plan (None: made here).

    Returns
    -------
    (F, J, 4, 4) skinning matrices, (F, N, 3) bodies, (F, M, 3) items and
    the (M,) bool mask of the vertices not moved by their binding (cloth,
    items skinned whole).
    """
    from ..dress.plan import plan as plan_dress
    from ..progress import set_verbosity, verbosity
    from .try_on import animate

    if ref_plan is None:
        ref_plan = plan_dress(reference, k=options.k)
    rec = FrameRecorder(every)
    opt = replace(options, start=0, end=None, fps=TRAINING_FPS, items="points", write_skinned_items=False,
                  measure_every=0, frame_sink=rec, skin_fit=False, skin_examples=None, mapping=None, max_frames=None,
                  clip_frames=None, velocities=False, carry_plan=None, hidden_body="none")
    level = verbosity()
    with tempfile.TemporaryDirectory(prefix="wearfit_skinfit_") as tmp, warnings.catch_warnings():
        # the shot itself says what this run would say again
        warnings.simplefilter("ignore")
        set_verbosity(0)
        try:
            animate(reference, target, training_motion(clips), Path(tmp) / "examples.usdc", opt, ref_plan=ref_plan)
        finally:
            set_verbosity(level)
    mats, bodies, items = rec.arrays()
    return mats, bodies, items, rec.free


def keep_layer_order(rest: np.ndarray, fitted: np.ndarray, normal: np.ndarray, clearance0: np.ndarray,
                     under: np.ndarray, over: np.ndarray, share: float = LAYER_SHARE) -> np.ndarray:
    """``fitted`` (M, 3) with the layers of the static dress ``rest`` (M, 3)
    kept: each vertex ``under[i]`` of an inner item moves out along its body
    ``normal`` (M, 3, unit) at most as far as the vertex ``over[i]`` of the
    item over it moved out, plus ``share`` of their static gap
    (``clearance0[over] - clearance0[under]``). Fitted item by item to the
    body alone, a top under a skirt came through it at the waist on 0.95 %
    of its covered vertices in the bind pose."""
    out = np.array(fitted, dtype=np.float64)
    if len(under) == 0:
        return out
    n = normal[under]
    mine = np.einsum("ij,ij->i", out[under] - rest[under], n)
    theirs = np.einsum("ij,ij->i", out[over] - rest[over], n)
    excess = mine - (theirs + share * (clearance0[over] - clearance0[under]))
    # one vertex may lie under several: the largest excess wins
    cut = np.zeros(len(out))
    np.maximum.at(cut, under, excess)
    out -= np.maximum(cut, 0.0)[:, None] * normal
    return out


def example_frames(reference, target, ref_plan, options) -> tuple | None:
    """:func:`training_frames`, or None with a warning when the example clips
    cannot be put on ``target`` (e.g. its skeleton's key joints do not pair
    with the clips'): the skinned items are then written as dressed."""
    from ..errors import WearfitError
    from ..progress import warn
    try:
        return training_frames(reference, target, ref_plan, options)
    except WearfitError as e:
        warn(f"{target.source}: the skinned items are written as dressed, not fitted to example poses: {e}")
        return None


def fit_skinned_items(skinned: list, body_faces: np.ndarray, rest_body: np.ndarray, frames: tuple,
                      keep: np.ndarray | None = None) -> tuple:
    """The skinned copies (meshes in the bind pose with ``joint_indices`` /
    ``joint_weights``, stacked in the shot's item order) on the body
    ``rest_body`` (N, 3) with ``body_faces``, their rest points fitted to the
    example ``frames`` (:func:`training_frames`); the vertices ``frames``
    marks free and those in ``keep`` (M,) bool keep theirs.

    Returns (list of meshes, (M,) float64 distance each rest point moved)."""
    mats, bodies, items, free = frames
    if keep is not None:
        free = np.asarray(free, dtype=bool) | np.asarray(keep, dtype=bool)
    rest = np.concatenate([np.asarray(s.points, dtype=np.float64) for s in skinned])
    if items.shape[1] != len(rest):
        raise ValueError(f"{items.shape[1]} example points for {len(rest)} skinned points")
    ji = np.concatenate([np.asarray(s.joint_indices) for s in skinned])
    jw = np.concatenate([np.asarray(s.joint_weights) for s in skinned])
    rows = np.flatnonzero(~np.asarray(free, dtype=bool))
    offsets = np.concatenate([[0], np.cumsum([len(s.points) for s in skinned])]).astype(np.int64)
    new = rest.copy()
    if len(rows):
        foot = SurfaceQuery(body_faces, rest_body).closest(rest)
        clear0 = foot["distance"]
        new[rows] = fit_rest_points(rest[rows], ji[rows], jw[rows], mats, items[:, rows], body_faces, bodies,
                                    clear0[rows])
        under, over = layer_pairs(rest, clear0, offsets)
        layered = keep_layer_order(rest, new, _unit_rows(foot["normal"]), clear0, under, over)
        new[rows] = layered[rows]  # the free and kept vertices stay where they are, whatever lies over them
    # the copies keep their names, faces and influences (copy_with_points)
    out = [s.copy_with_points(new[a:b]) for s, a, b in zip(skinned, offsets[:-1], offsets[1:])]
    return out, np.linalg.norm(new - rest, axis=1)
