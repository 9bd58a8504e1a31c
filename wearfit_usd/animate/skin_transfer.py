"""Copy skin weights from a body to item vertices (the classic game-engine
path, used as the LBS baseline of ``wearfit animate --mode lbs``).

Each item vertex takes the weights of the closest point on the body surface:
the barycentric blend of the closest triangle's three vertex weight vectors,
then the strongest ``max_influences`` kept and renormalised.
"""
from __future__ import annotations

import numpy as np

from ..geometry.closest import SurfaceQuery


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
