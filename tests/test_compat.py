"""Old flat module paths (before the one-package-per-stage layout) still
import for one release, warn, and give the new objects (wearfit_usd._compat)."""
from __future__ import annotations

import importlib
import sys

import pytest

import wearfit_usd
from wearfit_usd import _compat


def _import_old(name: str):
    """Import ``wearfit_usd.<name>`` afresh (the alias is dropped first, the
    new modules stay) and return (module, the DeprecationWarnings raised)."""
    full = f"wearfit_usd.{name}"
    sys.modules.pop(full, None)
    with pytest.warns(DeprecationWarning, match=full.replace(".", r"\.")) as record:
        module = importlib.import_module(full)
    return module, record


def _public(module) -> list[str]:
    names = getattr(module, "__all__", None) or [n for n in vars(module) if not n.startswith("_")]
    return [n for n in names if getattr(getattr(module, n), "__module__", None) == module.__name__]


@pytest.mark.parametrize("old", sorted(_compat.MOVED))
def test_every_old_path_imports_warns_and_gives_the_new_objects(old):
    new = [_compat.new_name(m) for m in _compat.MOVED[old]]
    if old == "mhclo":
        pytest.importorskip("benchmarks.peers.mhclo")
    module, record = _import_old(old)
    if len(new) == 1:
        assert module is importlib.import_module(new[0])
        assert new[0] in str(record[0].message)
    else:
        present = [importlib.import_module(m) for m in _compat._existing(tuple(new))]
        assert present
        for target in present:
            for name in _public(target)[:10]:
                with pytest.warns(DeprecationWarning):
                    assert getattr(module, name) is getattr(target, name)


def test_the_examples_of_the_issue():
    from wearfit_usd.geometry.closest import SurfaceQuery
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.transforms import matrix_to_euler

    sys.modules.pop("wearfit_usd.usd_io", None)
    with pytest.warns(DeprecationWarning, match=r"wearfit_usd\.io\.usd"):
        import wearfit_usd.usd_io as usd_io
    assert usd_io is importlib.import_module("wearfit_usd.io.usd")
    sys.modules.pop("wearfit_usd.clearance", None)
    with pytest.warns(DeprecationWarning, match=r"wearfit_usd\.geometry\.closest"):
        from wearfit_usd.clearance import SurfaceQuery as old_query
    assert old_query is SurfaceQuery
    sys.modules.pop("wearfit_usd.bvh", None)
    with pytest.warns(DeprecationWarning, match=r"wearfit_usd\.bvh"):
        from wearfit_usd.bvh import matrix_to_euler as old_euler
        from wearfit_usd.bvh import read_bvh as old_read
    assert old_read is read_bvh and old_euler is matrix_to_euler


def test_sub_modules_of_a_moved_package_are_the_new_ones():
    from wearfit_usd.demo.samples import body, motions

    sys.modules.pop("wearfit_usd.samples", None)
    sys.modules.pop("wearfit_usd.samples.motions", None)
    with pytest.warns(DeprecationWarning) as record:
        from wearfit_usd.samples.motions import CLIPS
    assert any("wearfit_usd.demo.samples.motions" in str(w.message) for w in record)
    assert CLIPS is motions.CLIPS
    assert sys.modules["wearfit_usd.samples.motions"] is motions
    with pytest.warns(DeprecationWarning):
        assert importlib.import_module("wearfit_usd.samples.body") is body


def test_redress_names_are_found_in_the_dress_package_modules():
    from wearfit_usd.geometry import mesh

    redress, _ = _import_old("redress")
    with pytest.warns(DeprecationWarning, match=r"wearfit_usd\.geometry\.mesh\.similarity_fit"):
        assert redress.similarity_fit is mesh.similarity_fit
    for name in ("dress", "plan", "apply", "untangle_items", "DressPlan"):
        with pytest.warns(DeprecationWarning, match=rf"wearfit_usd\.redress\.{name} is deprecated"):
            value = getattr(redress, name)
        assert value.__module__.startswith("wearfit_usd.dress.")
        assert not isinstance(value, type(sys))  # the function or class, not a module of that name
    with pytest.raises(AttributeError, match="no_such_name"):
        _ = redress.no_such_name


def test_a_missing_module_in_the_search_list_is_skipped():
    from wearfit_usd.geometry import mesh

    module = _compat._Searching("wearfit_usd.old_thing", ("wearfit_usd.dress.not_written_yet",
                                                         "wearfit_usd.geometry.mesh"))
    with pytest.warns(DeprecationWarning, match=r"wearfit_usd\.geometry\.mesh\.edges"):
        assert module.edges is mesh.edges
    assert "adjacency" in dir(module)


def test_packages_of_the_old_names_re_export_without_warning(recwarn):
    from wearfit_usd.animate import AnimateOptions, animate
    from wearfit_usd.animate.try_on import AnimateOptions as options
    from wearfit_usd.animate.try_on import animate as run
    from wearfit_usd.demo import run_demo
    from wearfit_usd.demo.demo import run_demo as demo_run
    from wearfit_usd.kernels import closest_candidates, warm_up  # noqa: F401

    assert animate is run and AnimateOptions is options and run_demo is demo_run
    assert not [w for w in recwarn if issubclass(w.category, DeprecationWarning)]


def test_the_finder_answers_for_old_paths_only():
    for name in ("wearfit_usd", "wearfit_usd.io", "wearfit_usd.io.usd", "wearfit_usd.animate",
                 "wearfit_usd.demo", "wearfit_usd.kernels", "wearfit_usd.redress.sub", "numpy"):
        assert _compat._targets(name) is None
    assert _compat._targets("wearfit_usd.usd_io") == ("wearfit_usd.io.usd",)
    assert _compat._targets("wearfit_usd.samples.items") == ("wearfit_usd.demo.samples.items",)
    assert sum(isinstance(f, _compat._Finder) for f in sys.meta_path) == 1
    _compat.install()  # idempotent
    assert sum(isinstance(f, _compat._Finder) for f in sys.meta_path) == 1
    assert wearfit_usd.__version__
