"""`wearfit fit` (name reserved; being implemented in its own issue)."""
from __future__ import annotations

from ..errors import WearfitError


def register(sub, common):
    p = sub.add_parser("fit", parents=[common], help="(not available yet)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    raise WearfitError("'wearfit fit' is not available in this version yet")
