"""Skeletons in motion: which joint is which, BVH clips onto USD skeletons,
and the skinning that poses a mesh from its joints.

- :mod:`.joint_maps` - automatic joint-name mapping between rig conventions (and user maps)
- :mod:`.retarget` - a BVH clip onto a USD skeleton (rotations transfer, lengths stay)
- :mod:`.skinning` - linear blend skinning on numpy arrays, matching UsdSkel
"""
