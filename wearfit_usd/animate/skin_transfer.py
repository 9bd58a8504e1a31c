"""Copy skin weights from a body to item vertices (the classic game-engine
path, used as the LBS baseline of ``wearfit animate --mode lbs``).

Each item vertex takes the weights of the closest point on the body surface:
the barycentric blend of the closest triangle's three vertex weight vectors,
then the strongest ``max_influences`` kept and renormalised. The function
lives in :mod:`wearfit_usd.dress.item_weights` beside the weights derived
from the K-triangle binding; it is re-exported here.
"""
from __future__ import annotations

from ..dress.item_weights import transfer_weights

__all__ = ["transfer_weights"]
