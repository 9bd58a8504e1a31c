"""Dressing: put the items authored on a reference body onto a fitted target body.

- :mod:`.plan` - the plan built once on the reference (regions, binding, rigid
  and loose parts, layer order): :func:`plan.plan`, :class:`plan.DressPlan`;
- :mod:`.apply` - a plan evaluated on a fitted body with the penetration,
  layer and untangle passes (:func:`apply.apply`), and :func:`apply.dress`,
  the whole dressing of one target;
- :mod:`.binding`, :mod:`.regions`, :mod:`.rigid_parts` - the K-triangle
  binding, body regions from skin weights, rigid parts' similarity transforms;
- :mod:`.layers`, :mod:`.corrections` - the layer order between items and the
  per-vertex corrections (push-out, spreading, loose-part smoothing);
- :mod:`.surface_layers` - outer layers kept over the inner items' triangles,
  not only their vertices (the dressing's last pass, and every animation frame);
- :mod:`.repair`, :mod:`.untangle`, :mod:`.body_stretch` - misfitting rigid
  parts released, folded or over-stretched patches re-solved within the
  body's own stretch range;
- :mod:`.metrics` - fit-quality figures of dressed items.
"""
