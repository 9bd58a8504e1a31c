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
