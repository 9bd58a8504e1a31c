"""Linear blend skinning (LBS) on numpy arrays, matching UsdSkel.

For rest-pose points ``p`` (internal world space, i.e. already through
geomBindTransform), bind transforms ``B`` and posed joint world transforms
``W`` (both internal world, row-vector 4x4):

    p' = sum_k w_k * [p, 1] @ inv(B[j_k]) @ W[j_k]

which is UsdSkel's ``ComputeSkinnedPoints`` re-expressed in internal space.
"""
from __future__ import annotations

import numpy as np

from .transforms import invert


def skinning_matrices(bind_world: np.ndarray, posed_world: np.ndarray) -> np.ndarray:
    """inv(bind) @ posed. bind_world (J, 4, 4), posed_world (..., J, 4, 4)
    -> (..., J, 4, 4)."""
    return invert(bind_world) @ posed_world


def skin_points(points: np.ndarray, joint_indices: np.ndarray, joint_weights: np.ndarray,
                skin_mats: np.ndarray) -> np.ndarray:
    """Skin (N, 3) points with (N, K) influences by (J, 4, 4) or (F, J, 4, 4)
    skinning matrices. Returns (N, 3) or (F, N, 3).

    Vectorised: per frame it blends the N (3x4) matrices and applies them,
    O(N*K) multiply-adds.
    """
    skin_mats = np.asarray(skin_mats, dtype=np.float64)
    single = skin_mats.ndim == 3
    if single:
        skin_mats = skin_mats[None]
    n, k = joint_indices.shape
    out = np.empty((skin_mats.shape[0], n, 3))
    # (F, N, K, 4, 3) would be large for long clips: loop over frames only.
    ph = np.concatenate([points, np.ones((n, 1))], axis=1)  # (N, 4)
    for f in range(skin_mats.shape[0]):
        m = skin_mats[f][:, :, :3]  # (J, 4, 3)
        blended = np.einsum("nk,nkij->nij", joint_weights, m[joint_indices])  # (N, 4, 3)
        out[f] = np.einsum("ni,nij->nj", ph, blended)
    return out[0] if single else out


def skin_mesh(mesh, skeleton, posed_world: np.ndarray) -> np.ndarray:
    """Skin a :class:`~wearfit_usd.model.Mesh` with influences on ``skeleton``
    to posed joint world transforms (J, 4, 4) or (F, J, 4, 4)."""
    if mesh.joint_indices is None:
        raise ValueError(f"mesh {mesh.name} has no skin weights")
    mats = skinning_matrices(skeleton.bind_world, posed_world)
    return skin_points(mesh.points, mesh.joint_indices, mesh.joint_weights, mats)
