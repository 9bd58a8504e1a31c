"""Body segmentation by skin weights: left/right leg, left/right arm, head, torso.

Joint names differ between rigs (``thigh_l`` vs ``LeftUpLeg``), so the limbs
are found from the skeleton's hierarchy and bind-pose geometry instead:

* the two feet are the lowest joints on each side (x > 0 is the character's
  left); a leg is the subtree, below the common ancestor of both feet, that
  holds that foot;
* the two hands are the joints farthest out along x on each side, the arms
  are found the same way below the hands' common ancestor;
* the head is the subtree (below the common ancestor of head top and a hand)
  holding the highest joint;
* every other joint is torso.

A body vertex belongs to the region whose joints carry most of its skin
weight. Internal space: Y up, metres.
"""
from __future__ import annotations

import numpy as np

TORSO, LEFT_LEG, RIGHT_LEG, LEFT_ARM, RIGHT_ARM, HEAD = range(6)
HIPS = 6  # torso triangles without leg weights (binding label for skirts, not a segment)
REGION_NAMES = ["torso", "left_leg", "right_leg", "left_arm", "right_arm", "head"]
N_REGIONS = len(REGION_NAMES)


def ancestors(parents: np.ndarray, j: int) -> list[int]:
    """``j`` and its ancestors up to the root, in that order."""
    out = [j]
    while parents[out[-1]] >= 0:
        out.append(int(parents[out[-1]]))
    return out


def _branch(parents: np.ndarray, a: int, b: int) -> int:
    """Child of the lowest common ancestor of joints a and b that leads to a
    (the root of a's branch), or a itself when b lies above a."""
    anc_b = set(ancestors(parents, b))
    path = ancestors(parents, a)
    for i, j in enumerate(path):
        if j in anc_b:
            return path[i - 1] if i > 0 else a
    return path[-1]


def subtree(parents: np.ndarray, root: int) -> np.ndarray:
    """(J,) bool: ``root`` and every joint below it (``parents[j] < j``)."""
    inside = np.zeros(len(parents), dtype=bool)
    inside[root] = True
    for j in range(len(parents)):  # parents[j] < j: one ordered sweep
        if parents[j] >= 0 and inside[parents[j]]:
            inside[j] = True
    return inside


def joint_regions(skeleton) -> np.ndarray:
    """(J,) region label of every joint (TORSO, LEFT_LEG, ... HEAD).

    Uses the rest pose (as authored; equal to the bind pose for most rigs):
    works for A-, T- or other standing poses with the usual conventions
    (Y up, character's left on +x). Not the bind pose, because a skeleton
    re-bound in an animation frame (:func:`animate`) keeps its rest pose,
    while a crouch or hanging arms would confuse the height tests.
    """
    parents = np.asarray(skeleton.parents)
    pos = skeleton.rest_world()[:, 3, :3]
    j = len(parents)
    labels = np.full(j, TORSO, dtype=np.int64)
    if j < 5:
        return labels
    x, y = pos[:, 0], pos[:, 1]
    # sides: off the midline by 1 % of the skeleton's height (a rig carried
    # onto a scan by a fit has its root a fraction of a millimetre off x = 0,
    # and a root counted as a side's lowest joint made the whole body a leg)
    mid = max(1e-4, 0.01 * float(np.ptp(y)))
    left, right = x > mid, x < -mid
    if not left.any() or not right.any():
        return labels
    lfoot = int(np.flatnonzero(left)[np.argmin(y[left])])
    rfoot = int(np.flatnonzero(right)[np.argmin(y[right])])
    lhand = int(np.flatnonzero(left)[np.argmax(x[left])])
    rhand = int(np.flatnonzero(right)[np.argmin(x[right])])
    top = int(np.argmax(y))
    for joint, other, lab in ((lfoot, rfoot, LEFT_LEG), (rfoot, lfoot, RIGHT_LEG),
                              (lhand, rhand, LEFT_ARM), (rhand, lhand, RIGHT_ARM)):
        root = _branch(parents, joint, other)
        sub = subtree(parents, root)
        labels[sub & (labels == TORSO)] = lab
    if labels[top] == TORSO:
        root = _branch(parents, top, lhand)
        sub = subtree(parents, root)
        labels[sub & (labels == TORSO)] = HEAD
    return labels


def region_shares(mesh, skeleton) -> np.ndarray:
    """(N, N_REGIONS) share of each vertex's skin weight held by each region."""
    if mesh.joint_indices is None or skeleton is None:
        raise ValueError(f"mesh {mesh.name} has no skin weights: cannot segment it")
    return weight_region_shares(mesh.joint_indices, mesh.joint_weights, skeleton)


def weight_region_shares(joint_indices: np.ndarray, joint_weights: np.ndarray, skeleton) -> np.ndarray:
    """(N, N_REGIONS) share of each vertex's skin weight held by each region,
    from (N, K) joint indices and weights into ``skeleton``'s joints."""
    jl = joint_regions(skeleton)
    lab = jl[np.asarray(joint_indices)]  # (N, K)
    acc = np.zeros((len(lab), N_REGIONS))
    rows = np.repeat(np.arange(len(lab)), lab.shape[1])
    np.add.at(acc, (rows, lab.ravel()), np.asarray(joint_weights).ravel())
    return acc


def vertex_regions(mesh, skeleton) -> np.ndarray:
    """(N,) region of every vertex of a skinned mesh: the region whose joints
    hold the largest share of its skin weight."""
    return np.argmax(region_shares(mesh, skeleton), axis=1)


def triangle_regions(faces: np.ndarray, vertex_labels: np.ndarray) -> np.ndarray:
    """(T,) region of each triangle: the majority label of its 3 vertices
    (ties: the first vertex's)."""
    lab = vertex_labels[faces]
    a, b, c = lab[:, 0], lab[:, 1], lab[:, 2]
    return np.where((b == c) & (a != b), b, a)
