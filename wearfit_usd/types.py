"""Type aliases for the array shapes of the public API.

numpy's typing cannot say a shape, so each alias names one and the comment
gives it; a signature ``def f(points: Points, faces: Faces) -> Scalars``
reads "(N, 3) float points, (T, 3) int triangles -> (N,) floats". Every
alias is a plain ``NDArray``: nothing is checked at run time.

Space conventions (see :mod:`wearfit_usd.transforms`): internal space is
Y up, metres; matrices are row-vector (``p' = [p, 1] @ M``).
"""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Points = NDArray[np.float64]        # (N, 3) positions
Vectors = NDArray[np.float64]       # (N, 3) directions, normals or displacements
Faces = NDArray[np.int64]           # (T, 3) vertex indices of triangles
Scalars = NDArray[np.float64]       # (N,) one value per point (or per triangle: (T,))
Mask = NDArray[np.bool_]            # (N,) or (T,) one flag per point or triangle
Matrix3 = NDArray[np.float64]       # (3, 3) row-vector linear map (rotation: p' = p @ R)
Matrix4 = NDArray[np.float64]       # (4, 4) row-vector affine map: p' = [p, 1] @ M
Matrices4 = NDArray[np.float64]     # (J, 4, 4) one row-vector affine map per joint (or frame)
JointIndices = NDArray[np.int64]    # (N, K) skin influences: joint index per point and slot
Weights = NDArray[np.float64]       # (N, K) skin influences: weight per point and slot (rows sum to 1)

__all__ = ["Points", "Vectors", "Faces", "Scalars", "Mask", "Matrix3", "Matrix4", "Matrices4",
           "JointIndices", "Weights"]
