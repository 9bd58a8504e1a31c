"""Which skinned meshes of one skeleton make up the body (plain numpy).

Characters come as one skinned body mesh, or as one skinned mesh per body
part (a native UsdSkel figure with 59 meshes: head, torso, upper arms,
finger segments...), sometimes with skinned clothes or hair bound to the
same skeleton. :func:`body_parts` tells them apart:

- a mesh is **layered on another** (an item: shirt, shoe, eyebrows, hair)
  when most of its vertices lie close to another mesh's surface (within 10 %
  of the mesh's own size, at most 5 % of the skeleton's extent) and on its
  outer side (along that surface's normal). A body part only touches its
  neighbours along a seam, or lies inside them (a foot in a shoe);
- every other mesh is a body part; they are merged for fitting. The one
  with the largest extent (bounding-box diagonal, not the most points: a
  detailed 0.5 m head must never be taken for a 1.8 m body) names the body.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..types import Faces, Points
from .closest import SurfaceQuery


@dataclass
class BodyChoice:
    """Result of :func:`body_parts`.

    parts: indices of the meshes that form the body, in input order.
    seed: the one with the largest extent (it names the body).
    layered: {mesh index: index of the mesh it lies over} for the others.
    extent_m: (bounding-box diagonal of the merged body, of the skeleton's joints).
    """
    parts: list[int]
    seed: int = 0
    layered: dict = field(default_factory=dict)
    extent_m: tuple = (0.0, 0.0)


def _diag(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.ptp(p, axis=0)))


def body_parts(meshes: list[tuple[Points, Faces]], joint_positions: Points,
               near: float = 0.1, near_max: float = 0.05, layered_fraction: float = 0.5,
               sample: int = 2000) -> BodyChoice:
    """Split the skinned meshes of one skeleton into body parts and items.

    Parameters
    ----------
    meshes : [(points (N_i, 3), faces (T_i, 3))], internal space (metres).
    joint_positions : (J, 3) the skeleton's joints (its extent caps the
        closeness test).
    near, near_max : a vertex is close to another mesh within ``near`` x its
        own mesh's extent, at most ``near_max`` x the skeleton's extent
        (and at least 0.2 % of it).
    layered_fraction : a mesh with more than this fraction of its vertices
        close to, and outside, one other mesh lies over it.
    sample : vertices tested per mesh (a fixed-seed subset of larger meshes).

    Returns
    -------
    :class:`BodyChoice`.
    """
    size = np.array([_diag(p) for p, _ in meshes])
    skel = _diag(np.asarray(joint_positions)) if len(joint_positions) > 1 else float(size.max())
    rng = np.random.default_rng(0)
    queries = {}
    layered = {}
    if len(meshes) > 1:
        for i, (p, _) in enumerate(meshes):
            q = p if len(p) <= sample else p[rng.choice(len(p), sample, replace=False)]
            tol = min(near * size[i], near_max * skel)
            tol = max(tol, 0.002 * skel)
            for j, (pj, fj) in enumerate(meshes):
                if j == i:
                    continue
                if j not in queries:
                    queries[j] = SurfaceQuery(fj, pj)
                r = queries[j].closest(q, k=4, signed=False)  # normal: the triangle's
                outside = np.einsum("ij,ij->i", q - r["point"], r["normal"]) > 0
                if np.mean((r["distance"] < tol) & outside) > layered_fraction:
                    layered[i] = j
                    break
    parts = [i for i in range(len(meshes)) if i not in layered]
    if not parts:  # layered on each other in a ring: keep the largest
        parts = [int(np.argmax(size))]
        layered.pop(parts[0], None)
    seed = max(parts, key=lambda i: size[i])
    merged = np.concatenate([meshes[i][0] for i in parts])
    return BodyChoice(parts=parts, seed=seed, layered=layered, extent_m=(_diag(merged), skel))
