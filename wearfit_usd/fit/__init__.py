"""Body fitting: deform the reference body onto a target body, no landmarks
(entry points :func:`~.body_fit.fit_body` and :func:`~.body_fit.fit_character`).

- :mod:`.body_fit` - the fit: options, result, non-rigid registration, final projection
- :mod:`.pose_align` - joint pairs, skeleton-driven posing, similarity alignment (joints or PCA + ICP)
- :mod:`.pockets` - pocket collapse: pull in what the target does not have, flipping nothing
- :mod:`.measures` - surface index, point-to-surface distances, chamfer, flipped triangles
"""
