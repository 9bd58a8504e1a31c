"""wearfit_usd: fit wearable items from a reference rigged body onto other
bodies and animate them with motion capture, in USD.

Pipeline stages, one module each:

- :mod:`wearfit_usd.usd_io` / :mod:`wearfit_usd.bvh` - reading and writing (edges)
- :mod:`wearfit_usd.skinning` - linear blend skinning (matches UsdSkel)
- :mod:`wearfit_usd.retarget` - BVH motion onto a USD skeleton
- :mod:`wearfit_usd.body_fit` - reference body onto a target body
- :mod:`wearfit_usd.binding` - K-triangle binding of item vertices
- :mod:`wearfit_usd.redress` - rebuild items on a new body, clearance, penetration
- :mod:`wearfit_usd.animate` - dynamic try-on over a clip
- :mod:`wearfit_usd.render` - offscreen previews (pyrender/OSMesa)
"""
__version__ = "0.1.0"
