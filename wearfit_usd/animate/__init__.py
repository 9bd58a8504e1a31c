"""Dynamic try-on: a BVH clip onto a target body wearing the reference's
items, evaluated frame by frame and written as a USD shot.

- :mod:`.try_on` - :func:`animate` and its options and report (the stage's entry point)
- :mod:`.frame_eval` - per-frame item points from body points (a dress plan built once)
- :mod:`.penetration_guard` - push item vertices that sink into the moving body back out
- :mod:`.contact_hold` - hold a skirt's bound parts on the skin they touch in the static dress
- (every frame, outer layers are kept over the items under them: :mod:`..dress.surface_layers`)
- :mod:`.skin_transfer` - copy body skin weights to items (the LBS baseline)

:func:`animate`, :class:`AnimateOptions`, :class:`AnimateReport` and
:func:`dress_items` are re-exported here (``wearfit_usd.animate`` was one
module before).
"""
from .try_on import AnimateOptions, AnimateReport, animate, dress_items

__all__ = ["AnimateOptions", "AnimateReport", "animate", "dress_items"]
