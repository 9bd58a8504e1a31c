"""Test helper: every point-array value of a USD stage, for bitwise comparisons."""
from __future__ import annotations

import numpy as np


def usd_points(path) -> dict:
    """Every point-array value of a stage at every time sample, as bytes."""
    from pxr import Usd
    stage = Usd.Stage.Open(str(path))
    out = {}
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            if "GfVec3f" not in attr.GetTypeName().cppTypeName:
                continue
            for t in attr.GetTimeSamples() or [Usd.TimeCode.Default()]:
                v = attr.Get(t)
                if v is not None:
                    out[str(prim.GetPath()), attr.GetName(), str(t)] = np.asarray(v).tobytes()
    return out
