"""wearfit_usd: fit wearable items from a reference rigged body onto other
bodies and animate them with motion capture, in USD.

One package per pipeline stage (internal space: Y up, metres, row-vector
matrices; geometry in plain numpy arrays):

- :mod:`wearfit_usd.io` - USD and BVH in and out (the edges of the pipeline)
- :mod:`wearfit_usd.motion` - joint-name maps, BVH retargeting, linear blend skinning
- :mod:`wearfit_usd.geometry` - closest points and signed distance, mesh helpers, sparse solves
- :mod:`wearfit_usd.fit` - the reference body onto a target body (pose, registration, pockets, measures)
- :mod:`wearfit_usd.dress` - bind the items to the body and rebuild them on the fitted target
- :mod:`wearfit_usd.animate` - dynamic try-on over a clip, frame by frame
- :mod:`wearfit_usd.kernels` - compiled inner loops (numba, optional) with their numpy twins
- :mod:`wearfit_usd.render` - offscreen previews (pyrender/OSMesa)
- :mod:`wearfit_usd.demo` - ``wearfit demo`` and its procedural samples
- :mod:`wearfit_usd.commands` - one module per ``wearfit`` subcommand (:mod:`wearfit_usd.cli`)

and beside them :mod:`~wearfit_usd.model` (Character, Mesh, Skeleton),
:mod:`~wearfit_usd.transforms` (matrices, quaternions, Euler angles),
:mod:`~wearfit_usd.types` (array-shape aliases), :mod:`~wearfit_usd.errors`
and :mod:`~wearfit_usd.progress`. The old flat module paths
(``wearfit_usd.usd_io``, ``wearfit_usd.clearance``...) still import, with a
DeprecationWarning, for one release (:mod:`wearfit_usd._compat`).
"""
from . import _compat

__version__ = "0.1.0"

_compat.install()
