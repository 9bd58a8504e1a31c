"""Rig an unrigged target body (a scan, an .obj/.ply, a USD mesh without
skin) from the reference: the reference body is fitted onto it
(:func:`body_fit.fit_character`), the reference skeleton is re-bound at the
fitted joints, and the skin weights are carried from the fitted reference
body onto the target's own vertices (closest surface point,
:func:`dress.item_weights.transfer_weights`). The target keeps its own mesh:
everything measured afterwards (penetrations, clearances) is measured
against it. Internal space (metres, Y up), numpy arrays.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..dress.item_weights import transfer_weights
from ..model import Character, Skeleton
from .body_fit import FitResult, fit_character


def fitted_skeleton(skeleton: Skeleton, joint_world: np.ndarray | None) -> Skeleton:
    """``skeleton`` re-bound at the (J, 4, 4) posed joint transforms of a fit
    (its bind pose when None), with that pose as its rest pose."""
    world = joint_world if joint_world is not None else skeleton.bind_world
    out = Skeleton(skeleton.joint_names, skeleton.joint_paths, skeleton.parents,
                   np.asarray(world), skeleton.rest_local, skeleton.skel_to_world, skeleton.path)
    out.rest_local = out.local_from_world(out.bind_world)  # rest pose = new bind pose
    return out


@dataclass
class RiggedTarget:
    """character: the target body with the reference skeleton and carried
    weights (its own points and topology); fit: the reference body fitted
    onto it (:class:`body_fit.FitResult`, reference topology)."""
    character: Character
    fit: FitResult


def rig_from_reference(ref: Character, target: Character, fit_options=None,
                       max_influences: int | None = None) -> RiggedTarget:
    """Give ``target`` (any body mesh, skeleton ignored) ``ref``'s skeleton and
    skin weights.

    Parameters
    ----------
    ref : Character
        The rigged reference (skinned body, skeleton).
    target : Character
        The body to rig, internal space; its up axis and units are kept.
    fit_options : dict or body_fit.FitOptions, optional
        Passed to :func:`body_fit.fit_character`.
    max_influences : int, optional
        Influences per target vertex (default: as many as the reference body has).

    Returns
    -------
    RiggedTarget
        ``character.body`` has (N_target, I) joint indices and weights into
        ``character.skeleton`` (the reference's joints at the fitted pose).
    """
    if ref.skeleton is None or ref.body.joint_indices is None:
        raise ValueError(f"{ref.source}: the reference has no skinned body to carry a rig from")
    plain = replace(target, skeleton=None)
    res = fit_character(ref, plain, fit_options)
    skel = fitted_skeleton(ref.skeleton, res.joint_world)
    k = max_influences or ref.body.joint_indices.shape[1]
    ji, jw = transfer_weights(res.points, ref.body.faces, ref.body.joint_indices, ref.body.joint_weights,
                              target.body.points, ref.skeleton.n_joints, max_influences=k)
    body = target.body.copy_with_points(target.body.points)
    body.joint_indices, body.joint_weights = ji, jw
    return RiggedTarget(replace(target, skeleton=skel, body=body), res)
