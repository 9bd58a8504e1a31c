"""Old home of the dressing code, split by subject into :mod:`plan`,
:mod:`layers`, :mod:`corrections`, :mod:`apply` and :mod:`repair`
(removed once every caller imports from those)."""
from .apply import DressResult, apply, dress, fitted_body_points  # noqa: F401
from .corrections import (LOOSE_FULL, LOOSE_ITERATIONS, LOOSE_START, SPREAD_CLEARANCE_DRIFT, SPREAD_LENGTH,  # noqa: F401
                          SPREAD_RINGS, LooseSmoother, looseness, off_skin, push_out, spread_corrections)
from .layers import LAYER_MIN_GAP, LAYER_RADIUS, keep_layers, layer_gaps, layer_order, layer_pairs  # noqa: F401
from .plan import FAR_FROM_BODY, DressPlan, item_labels, plan  # noqa: F401
from .repair import (RIGID_RELEASE, RIGID_RELEASE_DEPTH, UNTANGLE_CLEARANCE_DRIFT, release_misfits,  # noqa: F401
                     stretch_limits, untangle_items)
from ..geometry.mesh import adjacency, edges, similarity_fit  # noqa: F401
