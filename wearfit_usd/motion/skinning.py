"""Linear blend skinning (LBS) on numpy arrays, matching UsdSkel.

For rest-pose points ``p`` (internal world space, i.e. already through
geomBindTransform), bind transforms ``B`` and posed joint world transforms
``W`` (both internal world, row-vector 4x4):

    p' = sum_k w_k * [p, 1] @ inv(B[j_k]) @ W[j_k]

which is UsdSkel's ``ComputeSkinnedPoints`` re-expressed in internal space.

Because ``p`` and the weights are fixed, the sum is linear in the stacked
skinning matrices: with ``A[n, 4j + i] = w_nj * [p_n, 1]_i`` (sparse, N x 4J,
built once by :class:`Skinner`), ``p' = A @ S`` where ``S`` stacks the top
3 columns of the J skinning matrices (4J x 3). One sparse product per frame,
or one for many frames at once.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..transforms import invert
from ..types import JointIndices, Matrices4, Points, Weights


def skinning_matrices(bind_world: Matrices4, posed_world: np.ndarray) -> np.ndarray:
    """inv(bind) @ posed. bind_world (J, 4, 4), posed_world (..., J, 4, 4)
    -> (..., J, 4, 4)."""
    return invert(bind_world) @ posed_world


class Skinner:
    """LBS of fixed rest points, built once, evaluated per frame.

    points (N, 3), joint_indices / joint_weights (N, K), n_joints J.
    """

    def __init__(self, points: Points, joint_indices: JointIndices, joint_weights: Weights,
                 n_joints: int | None = None):
        points = np.asarray(points, dtype=np.float64)
        ji = np.asarray(joint_indices, dtype=np.int64)
        jw = np.asarray(joint_weights, dtype=np.float64)
        n, k = ji.shape
        j = int(n_joints if n_joints is not None else ji.max() + 1)
        ph = np.concatenate([points, np.ones((n, 1))], axis=1)  # (N, 4)
        rows = np.repeat(np.arange(n), k * 4)
        cols = (ji[:, :, None] * 4 + np.arange(4)).ravel()
        vals = (jw[:, :, None] * ph[:, None, :]).ravel()
        self.matrix = sp.csr_matrix((vals, (rows, cols)), shape=(n, 4 * j))
        self.matrix.sum_duplicates()
        self.n_joints = j

    def __call__(self, skin_mats: np.ndarray) -> np.ndarray:
        """(J, 4, 4) -> (N, 3); (F, J, 4, 4) -> (F, N, 3)."""
        m = np.asarray(skin_mats, dtype=np.float64)
        if m.ndim == 3:
            return self.matrix @ m[:, :, :3].reshape(-1, 3)
        f = m.shape[0]
        stacked = m[:, :, :, :3].reshape(f, -1, 3).transpose(1, 0, 2).reshape(-1, 3 * f)
        out = self.matrix @ stacked  # (N, F*3)
        return out.reshape(-1, f, 3).transpose(1, 0, 2)


def skin_points(points: Points, joint_indices: JointIndices, joint_weights: Weights,
                skin_mats: np.ndarray) -> np.ndarray:
    """Skin (N, 3) points with (N, K) influences by (J, 4, 4) or (F, J, 4, 4)
    skinning matrices. Returns (N, 3) or (F, N, 3). Builds a
    :class:`Skinner` each call: keep one yourself when skinning many frames."""
    skin_mats = np.asarray(skin_mats)
    return Skinner(points, joint_indices, joint_weights, skin_mats.shape[-3])(skin_mats)


def skin_mesh(mesh, skeleton, posed_world: np.ndarray) -> np.ndarray:
    """Skin a :class:`~wearfit_usd.model.Mesh` with influences on ``skeleton``
    to posed joint world transforms (J, 4, 4) or (F, J, 4, 4)."""
    if mesh.joint_indices is None:
        raise ValueError(f"mesh {mesh.name} has no skin weights")
    mats = skinning_matrices(skeleton.bind_world, posed_world)
    return skin_points(mesh.points, mesh.joint_indices, mesh.joint_weights, mats)
