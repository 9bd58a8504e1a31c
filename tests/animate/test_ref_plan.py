"""`animate(..., ref_plan=P)`: a reference's dressing plan built once and
reused by every clip and target gives the shots a fresh plan gives, and is
left unchanged by them (what `wearfit batch` relies on)."""
from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest
import scipy.sparse as sp

from tests.conftest import BVH_DIR, USD_DIR
from tests.usd_values import usd_points as shot_points
from wearfit_usd.animate.try_on import AnimateOptions, animate
from wearfit_usd.dress.plan import plan
from wearfit_usd.io.bvh import read_bvh
from wearfit_usd.io.usd import read_character

STATISTICS = {"timings", "n_solves"}


def fingerprint(obj, where: str = "plan", out: dict | None = None, seen: set | None = None) -> dict:
    """Every array, sparse matrix and plain value reachable from ``obj``
    (dataclass fields, containers, public attributes of other objects) as
    ``{path: digest}``; private (``_``) attributes are lazy caches and left
    out, so are the statistics (timings, a solver's count of solves)."""
    out = {} if out is None else out
    seen = set() if seen is None else seen
    if isinstance(obj, np.ndarray):
        out[where] = f"{obj.dtype}{obj.shape}" + hashlib.sha256(np.ascontiguousarray(obj).tobytes()).hexdigest()
        return out
    if sp.issparse(obj):
        parts = [getattr(obj, a) for a in ("data", "indices", "indptr", "row", "col") if hasattr(obj, a)]
        out[where] = f"{obj.format}{obj.shape}" + "".join(
            hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest() for a in parts)
        return out
    if obj is None or isinstance(obj, (bool, int, float, str, np.generic)):
        out[where] = repr(obj)
        return out
    if id(obj) in seen:
        return out
    seen.add(id(obj))
    if isinstance(obj, dict):
        items = [(repr(k), v) for k, v in obj.items()]
    elif isinstance(obj, (list, tuple)):
        items = list(enumerate(obj))
    elif dataclasses.is_dataclass(obj):
        items = [(f.name, getattr(obj, f.name)) for f in dataclasses.fields(obj)]
    elif hasattr(obj, "__dict__"):
        items = [(k, v) for k, v in vars(obj).items() if not k.startswith("_")]
    else:
        out[where] = type(obj).__name__
        return out
    for k, v in items:
        if k in STATISTICS:
            continue
        if not callable(v) or isinstance(v, np.ndarray) or sp.issparse(v) or hasattr(v, "__dict__"):
            fingerprint(v, f"{where}.{k}", out, seen)
    return out


@pytest.fixture(scope="module")
def walk():
    return read_bvh(BVH_DIR / "cmu_07_01_walk.bvh")


@pytest.mark.slow
def test_rebound_leaves_the_plan_unchanged(ref_female):
    p = plan(ref_female, k=5)
    before = fingerprint(p)
    moved = p.ref_points + np.array([0.0, 0.01, 0.0])
    q = p.rebound(p.ref_body * 1.01, moved)
    assert fingerprint(p) == before
    assert np.array_equal(q.ref_points, moved) and not np.array_equal(q.ref_points, p.ref_points)


@pytest.mark.slow
@pytest.mark.parametrize("targets", [("body_female_thin", "body_female_heavy_remeshed")])
def test_one_plan_serves_every_target_and_clip(tmp_path, ref_female, walk, targets):
    """One prebuilt plan, two targets (same topology as the reference and
    remeshed) and two clip ranges: the shots equal those of fresh plans
    bitwise, and the plan is unchanged after all of them."""
    p = plan(ref_female, k=5)
    before = fingerprint(p)
    assert len(before) > 50  # the walk reaches the plan's arrays
    for name in targets:
        tgt = read_character(USD_DIR / f"{name}.usdc")
        for start in (1, 41):
            opts = AnimateOptions(k=5, start=start, end=start + 16, fps=30, measure_every=2)
            fresh = animate(ref_female, tgt, walk, tmp_path / f"{name}_{start}_fresh.usdc", opts)
            reused = animate(ref_female, tgt, walk, tmp_path / f"{name}_{start}_reused.usdc", opts, ref_plan=p)
            assert fresh.frames == reused.frames == 4
            assert fresh.per_frame_penetration == reused.per_frame_penetration
            a = shot_points(tmp_path / f"{name}_{start}_fresh.usdc")
            b = shot_points(tmp_path / f"{name}_{start}_reused.usdc")
            assert a.keys() == b.keys() and a == b, (name, start)
            assert fingerprint(p) == before, (name, start)
