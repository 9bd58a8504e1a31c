"""Old flat module paths, kept importable for one release (issue 16).

The package was split into one sub-package per pipeline stage. Importing an
old path (``import wearfit_usd.usd_io``, ``from wearfit_usd.clearance import
SurfaceQuery``, ``from wearfit_usd.samples.motions import CLIPS``...) still
works and emits a :class:`DeprecationWarning` naming the new path. This
module is the one mechanism: a :data:`sys.meta_path` finder installed by
``wearfit_usd/__init__.py`` that answers only for the names in
:data:`MOVED`, so it never shadows a module that exists.

- An old module that became exactly one new module is that module
  (``wearfit_usd.clearance is wearfit_usd.geometry.closest``); its
  sub-modules follow (``wearfit_usd.samples.body`` is
  ``wearfit_usd.demo.samples.body``).
- An old module whose names now live in several modules is a small module
  that looks each name up in them, in order, the first time it is read
  (``wearfit_usd.redress`` searches the ``dress`` package's modules, so it
  keeps working while that package is re-split; a module of the list that
  does not exist is skipped).

``wearfit_usd.animate``, ``wearfit_usd.kernels`` and ``wearfit_usd.demo``
are packages of the old names: their ``__init__`` re-exports the old
public names, with no warning.

Remove this module, its line in ``wearfit_usd/__init__.py`` and
``tests/test_compat.py`` in the release after the move.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types
import warnings

PACKAGE = __name__.rpartition(".")[0]  # "wearfit_usd"

#: old module (under ``wearfit_usd.``) -> new module(s), relative to
#: ``wearfit_usd`` unless absolute (``benchmarks...``); several: names are
#: looked up in that order.
MOVED: dict[str, tuple[str, ...]] = {
    "usd_io": ("io.usd",),
    "usd_shot": ("io.usd_shot",),
    "usd_validate": ("io.usd_validate",),
    "bvh": ("io.bvh", "transforms"),  # the Euler helpers went to transforms
    "joint_maps": ("motion.joint_maps",),
    "retarget": ("motion.retarget",),
    "skinning": ("motion.skinning",),
    "clearance": ("geometry.closest",),
    "sparse_solve": ("geometry.sparse_solve",),
    "body_fit": ("fit.body_fit", "fit.measures"),
    "pose_align": ("fit.pose_align",),
    "fit_collapse": ("fit.pockets",),
    "binding": ("dress.binding",),
    "regions": ("dress.regions",),
    "rigid_parts": ("dress.rigid_parts",),
    "body_stretch": ("dress.body_stretch",),
    "metrics": ("dress.metrics",),
    "untangle": ("dress.untangle",),
    "redress": ("dress.plan", "dress.layers", "dress.corrections", "dress.apply", "dress.repair",
                "dress.untangle", "dress.binding", "dress.regions",
                "dress.rigid_parts", "dress.body_stretch", "geometry.mesh"),
    "frame_eval": ("animate.frame_eval",),
    "penetration_guard": ("animate.penetration_guard",),
    "skin_transfer": ("animate.skin_transfer",),
    "samples": ("demo.samples",),
    "mhclo": ("benchmarks.peers.mhclo",),  # only in a checkout: the benchmarks are not installed
}


def new_name(module: str) -> str:
    """Absolute name of a new module given as in :data:`MOVED`."""
    return module if module.startswith("benchmarks.") else f"{PACKAGE}.{module}"


def _targets(fullname: str) -> tuple[str, ...] | None:
    """New module names for the old module ``fullname``, or None if it is not an old path."""
    head, dot, tail = fullname.partition(".")
    if head != PACKAGE or not dot:
        return None
    first, _, rest = tail.partition(".")
    new = MOVED.get(first)
    if new is None:
        return None
    if rest:  # a sub-module of a moved package (samples.body)
        return (f"{new_name(new[0])}.{rest}",) if len(new) == 1 else None
    return tuple(new_name(m) for m in new)


def _warn(message: str, stacklevel: int) -> None:
    warnings.warn(f"{message} (the old path goes in the next release)", DeprecationWarning,
                  stacklevel=stacklevel + 1)


def _existing(modules: tuple[str, ...]) -> list[str]:
    found = []
    for m in modules:
        try:
            if importlib.util.find_spec(m) is not None:
                found.append(m)
        except ModuleNotFoundError:  # its parent package is missing (benchmarks outside a checkout)
            pass
    return found


class _Searching(types.ModuleType):
    """An old module whose names are looked up in several new modules."""

    def __init__(self, name: str, sources: tuple[str, ...]):
        super().__init__(name, f"Deprecated: the names of {name} now live in {', '.join(sources)}.")
        self.__sources__ = sources

    def _modules(self):
        for source in self.__sources__:
            try:
                yield importlib.import_module(source)
            except ModuleNotFoundError as exc:
                if exc.name != source:  # the module exists but something it imports does not
                    raise

    def __getattr__(self, attr: str):
        if attr.startswith("__"):
            raise AttributeError(attr)
        found = [getattr(m, attr) for m in self._modules() if hasattr(m, attr)]
        if found:
            # a function or class before a module object of the same name
            # (``apply`` the function, not the module a sibling imported)
            value = next((v for v in found if not isinstance(v, types.ModuleType)), found[0])
            setattr(self, attr, value)  # found once, then an ordinary attribute
            homes = [m.__name__ for m in self._modules() if getattr(m, attr, None) is value]
            defined = getattr(value, "__module__", None)  # a function's or class's own module
            home = defined if defined in homes else homes[0]
            _warn(f"{self.__name__}.{attr} is deprecated, use {home}.{attr}", stacklevel=2)
            return value
        raise AttributeError(f"module {self.__name__!r} has no attribute {attr!r} (searched "
                             f"{', '.join(self.__sources__)})")

    def __dir__(self):
        names = set(super().__dir__())
        for module in self._modules():
            names.update(n for n in dir(module) if not n.startswith("__"))
        return sorted(names)


class _Loader(importlib.abc.Loader):
    def __init__(self, targets: tuple[str, ...]):
        self.targets = targets

    def create_module(self, spec):
        return None if len(self.targets) == 1 else _Searching(spec.name, self.targets)

    def exec_module(self, module):
        # stacklevel 2 skips the import machinery's frames: the warning points at the import
        if len(self.targets) == 1:
            _warn(f"{module.__name__} is deprecated, import {self.targets[0]}", stacklevel=2)
        else:
            _warn(f"{module.__name__} is deprecated, its names are in "
                  f"{', '.join(_existing(self.targets))}", stacklevel=2)
        if len(self.targets) == 1:
            # the import returns what sys.modules holds after exec_module: the new module itself
            sys.modules[module.__name__] = importlib.import_module(self.targets[0])


class _Finder(importlib.abc.MetaPathFinder):
    """Answers for the old paths only (:data:`MOVED`); everything else is left
    to the other finders."""

    def find_spec(self, fullname, path=None, target=None):
        targets = _targets(fullname)
        if targets is None:
            return None
        return importlib.util.spec_from_loader(fullname, _Loader(targets))


def install() -> None:
    """Put the finder first on :data:`sys.meta_path` (once): first, so that
    ``wearfit_usd.samples.body`` is not found a second time, as a copy, in
    the new package's folder."""
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())
