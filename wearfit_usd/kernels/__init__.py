"""Compiled inner loops (numba, optional) with their numpy twins.

Callers import the kernels from this package; which module of it holds a
kernel is the package's own business.
"""
from .compiled import (HAVE_NUMBA, RadiusGrid, _similarity_place, _similarity_transforms, assign_rows,
                       binding_eval, closest_candidates, closest_signed, face_normals, vertex_normals, warm_up)

__all__ = ["HAVE_NUMBA", "RadiusGrid", "assign_rows", "binding_eval", "closest_candidates", "closest_signed",
           "face_normals", "vertex_normals", "warm_up", "_similarity_place", "_similarity_transforms"]
