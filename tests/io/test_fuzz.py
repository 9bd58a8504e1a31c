"""Property-based fuzzing of the BVH and USD readers (hypothesis, fixed seed).

Property: for any edit of a valid file, reading it either succeeds with
finite results (joint transforms over every frame; mesh points and joint
transforms) or raises the project's own error (a :class:`WearfitError`)
whose message starts with the file's path (and, for BVH syntax, carries a
line). Never another exception, never NaN/inf out. The long run over 50,000
mutations is benchmarks/bench_fuzz.py.
"""
from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.test_bad_input import MINI_BVH
from tests.tiny_stage import TINY_USDA
from wearfit_usd.errors import BVHError, WearfitError
from wearfit_usd.io.bvh import read_bvh
from wearfit_usd.io.usd import read_character

FUZZ = settings(max_examples=300, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

_EXTREME = ["1e308", "-1e308", "1e200", "5e-324", "nan", "inf", "-inf", "0", "-0", "1e-300",
            "99999999999999999999", "-1", "86400", "1e", "", "x", "{", "}", "JOINT", "End Site",
            "CHANNELS 3", "OFFSET", "ROOT a", "MOTION", "\ufeff"]
_USD_EXTREME = ["1e308", "-1e308", "1e39", "5e-324", "nan", "inf", "-inf", "0", "-0", "-1",
                "2147483647", "-2147483648", "99999999999", "3", "4", "7"]
_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e-?\d+)?")


def _edits(n_tokens: int):
    """(position, replacement) edits of a token list of length ``n_tokens``."""
    return st.lists(st.tuples(st.integers(0, n_tokens - 1),
                              st.one_of(st.sampled_from(_EXTREME), st.text(max_size=4))),
                    min_size=1, max_size=3)


def _apply(text: str, edits, pattern=r"\S+") -> str:
    spans = [m.span() for m in re.finditer(pattern, text)]
    out = list(text)
    for pos, rep in sorted(edits, key=lambda e: -spans[e[0] % len(spans)][0]):
        a, b = spans[pos % len(spans)]
        out[a:b] = [rep]
    return "".join(out)


def _check_bvh(path: Path):
    try:
        m = read_bvh(path)
    except WearfitError as exc:
        assert str(exc).startswith(str(path)), exc
        if isinstance(exc, BVHError) and "file not found" not in str(exc):
            assert exc.line is not None or "joint" in str(exc) or "scale" in str(exc), exc
        return "error"
    if m.n_frames:
        assert np.isfinite(m.global_transforms()).all()
    assert np.isfinite(m.offsets).all()
    return "ok"


_N_BVH_TOKENS = len(MINI_BVH.split())


@FUZZ
@given(edits=_edits(_N_BVH_TOKENS), drop_lines=st.lists(st.integers(0, 40), max_size=2))
def test_fuzz_bvh_reader(tmp_path_factory, edits, drop_lines):
    text = _apply(MINI_BVH, edits)
    lines = text.splitlines()
    for i in sorted(set(drop_lines), reverse=True):
        if i < len(lines):
            del lines[i]
    path = tmp_path_factory.mktemp("bvh") / "f.bvh"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogatepass")
    _check_bvh(path)


_N_USD_NUMBERS = len(_NUMBER.findall(TINY_USDA.split(")\n", 1)[1]))


@FUZZ
@given(edits=st.lists(st.tuples(st.integers(0, _N_USD_NUMBERS - 1), st.sampled_from(_USD_EXTREME)),
                      min_size=1, max_size=3))
def test_fuzz_usd_reader(tmp_path_factory, edits):
    head, body = TINY_USDA.split(")\n", 1)
    text = head + ")\n" + _apply(body, edits, _NUMBER.pattern)
    path = tmp_path_factory.mktemp("usd") / "s.usda"
    path.write_text(text)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            c = read_character(path)
    except WearfitError as exc:
        assert str(exc).startswith(str(path)), exc
        return
    assert np.isfinite(c.body.points).all()
    assert all(np.isfinite(m.points).all() for m in c.items)
    assert np.isfinite(c.skeleton.bind_world).all() and np.isfinite(c.skeleton.rest_local).all()
    assert np.isfinite(c.body.joint_weights).all()
