"""Geometry every stage shares, on plain numpy arrays.

- :mod:`.closest` - closest points and signed distances to a triangle mesh, face/vertex normals
- :mod:`.mesh` - adjacency, components, edges, the one zero-area test, the one Umeyama fit
- :mod:`.sparse_solve` - sparse SPD solves re-using one symbolic analysis (CHOLMOD or splu)
"""
