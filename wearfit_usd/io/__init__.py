"""The edges of the pipeline: USD and BVH in and out (everything inside is
internal space: Y up, metres, row-vector matrices).

- :mod:`.usd` - read rigged characters into :mod:`wearfit_usd.model`, write static rigged stages
- :mod:`.usd_shot` - stream an animated shot (SkelAnimation + time-sampled items, value clips)
- :mod:`.usd_author` - USD authoring shared by the writers (stage layout, skeleton, meshes)
- :mod:`.usd_validate` - validate a stage with usd-core's registered validators
- :mod:`.bvh` - BVH motion capture: reader, forward kinematics, writer
- :mod:`.atomic` - write beside the destination and rename into place (no half-written file)
"""
