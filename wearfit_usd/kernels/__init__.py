"""Compiled inner loops (numba, optional) beside their numpy twins.

One module per thing computed, each holding the numba kernels and their
numpy twins side by side: :mod:`.binding` (item points from body points:
binding product, rigid-part similarities, smoothing right side, row
scatters), :mod:`.normals` (face, vertex and pseudo-normals),
:mod:`.closest` (closest point among candidate triangles, signed),
:mod:`.grid` (nearest point within a radius), :mod:`.guard` (the
penetration guard's per-frame kernels), :mod:`.layers` (the layer pass's ray search), :mod:`.strain` (the strain limit's
per-frame pass); :mod:`.jit` is the numba switch and
:mod:`.warm` compiles everything ahead of time. Each public kernel runs
compiled when numba is installed and its numpy twin otherwise (set
WEARFIT_NO_NUMBA=1 to force the numpy paths).

Callers import the kernels from this package; which module of it holds a
kernel is the package's own business.
"""
from .binding import (
                      add_rows,
                      assign_rows,
                      binding_eval,
                      binding_eval_rows,
                      diffusion_rhs,
                      similarity_place,
                      similarity_transforms,
)
from .closest import closest_candidates, closest_params, closest_signed
from .grid import GridArrays, RadiusGrid
from .guard import GuardBody, GuardState, guard_estimate, guard_frame
from .jit import HAVE_NUMBA
from .layers import first_hits
from .normals import (
                      corner_normals_numpy,
                      face_normal_sums,
                      face_normals,
                      vertex_incidence,
                      vertex_normals,
                      vertex_pseudo_normals_numpy,
)
from .strain import (
    StrainCaps,
    StrainRest,
    clear_caps,
    edge_incidence,
    new_caps,
    strain_frame,
    wavefront_levels,
    weld_groups,
)
from .warm import warm_up

__all__ = ["HAVE_NUMBA", "GridArrays", "GuardBody", "GuardState", "RadiusGrid", "add_rows", "assign_rows",
           "binding_eval", "binding_eval_rows", "closest_candidates", "closest_params", "closest_signed",
           "corner_normals_numpy", "diffusion_rhs", "face_normal_sums", "face_normals", "first_hits",
           "guard_estimate", "guard_frame", "similarity_place", "similarity_transforms", "vertex_incidence",
           "vertex_normals", "vertex_pseudo_normals_numpy", "warm_up", "StrainRest", "strain_frame", "edge_incidence",
           "StrainCaps", "new_caps", "clear_caps", "weld_groups", "wavefront_levels"]
