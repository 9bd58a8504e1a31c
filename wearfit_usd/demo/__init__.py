"""``wearfit demo``: the whole pipeline on the project's own procedural
samples, no download and no shared data set needed.

- :mod:`.demo` - run the demo: samples, dressing, shots, previews, report
- :mod:`.samples` - procedural rigged body, wearable items and BVH clips

:func:`run_demo`, :func:`markdown` and :data:`DEFAULT_SHOTS` are re-exported
here (``wearfit_usd.demo`` was one module before).
"""
from .demo import DEFAULT_SHOTS, markdown, run_demo

__all__ = ["DEFAULT_SHOTS", "markdown", "run_demo"]
