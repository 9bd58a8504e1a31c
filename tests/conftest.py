"""Shared fixtures: the real data set beside the checkout (../shared/data)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("WEARFIT_DATA", REPO.parent / "shared" / "data"))
USD_DIR = DATA / "usd"
BVH_DIR = DATA / "bvh"
ITEMS_DIR = DATA / "items"

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")


def _require(path: Path) -> Path:
    if not path.exists():
        pytest.fail(f"test data missing: {path} (the shared data set must sit beside the checkout)")
    return path


@pytest.fixture(scope="session")
def data_dir() -> Path:
    return _require(DATA)


@pytest.fixture(scope="session")
def usd_dir() -> Path:
    return _require(USD_DIR)


@pytest.fixture(scope="session")
def bvh_dir() -> Path:
    return _require(BVH_DIR)


@pytest.fixture(scope="session")
def ref_male(usd_dir):
    from wearfit_usd.io.usd import read_character
    return read_character(usd_dir / "ref_male.usda")


@pytest.fixture(scope="session")
def ref_female(usd_dir):
    from wearfit_usd.io.usd import read_character
    return read_character(usd_dir / "ref_female.usda")


@pytest.fixture(scope="session")
def ref_female_longskirt(usd_dir):
    from wearfit_usd.io.usd import read_character
    return read_character(usd_dir / "ref_female_longskirt.usda")


# --------------------------------------------------------------------------
# markers: `data` (needs ../shared/data) is given here to every test whose own
# code or whose fixtures read the data set, so no test can forget it; `slow`
# is set by hand on tests that take seconds. The fast tier:
#   python3 -m pytest -m "not data and not slow"
_DATA_NAMES = ("DATA", "USD_DIR", "BVH_DIR", "ITEMS_DIR", "data_dir", "usd_dir", "bvh_dir")


def _reads_data(func, module=None, seen=None) -> bool:
    """Whether ``func``'s source, or a helper of its module that it calls,
    names the data set."""
    import inspect
    import re
    seen = set() if seen is None else seen
    if func is None or func in seen:
        return False
    seen.add(func)
    try:
        src = inspect.getsource(func)
    except (OSError, TypeError):
        return False
    if re.search(r"\b(" + "|".join(_DATA_NAMES) + r")\b", src):
        return True
    module = module or inspect.getmodule(func)
    for name in set(re.findall(r"\b([A-Za-z_]\w*)\s*\(", src)):
        helper = getattr(module, name, None)
        if inspect.isfunction(helper) and helper.__module__ == module.__name__:
            if _reads_data(helper, module, seen):
                return True
    return False


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.get_closest_marker("data"):
            continue
        funcs = [getattr(item, "function", None)]
        info = getattr(item, "_fixtureinfo", None)
        if info is not None:
            for name in info.names_closure:
                if name in _DATA_NAMES:
                    funcs = [None]
                    item.add_marker(pytest.mark.data)
                    break
                for fdef in info.name2fixturedefs.get(name, ()):
                    funcs.append(fdef.func)
            else:
                if any(f is not None and _reads_data(f) for f in funcs):
                    item.add_marker(pytest.mark.data)
