"""Target and item-output options shared by `dress` and `animate` (not a
command): reading any target (:func:`io.target.read_target`), rigging an
unrigged one from the reference (:func:`fit.rig.rig_from_reference`), and
the ``--items points|skinned|both`` choice."""
from __future__ import annotations

import argparse

import numpy as np

ITEM_MODES = ("points", "skinned", "both")


def add_target_options(p, items_default: str | None) -> None:
    """``--rig-from-reference`` and (with ``items_default``) ``--items`` on a
    command's parser."""
    p.add_argument("--rig-from-reference", action=argparse.BooleanOptionalAction, default=None,
                   help="fit the reference body onto the target and carry its skeleton and skin weights "
                        "over, so an unrigged target (a scan: USD mesh without skin, .obj, .ply) is rigged "
                        "and dressed in one step (default: on when the target has no skeleton); "
                        "everything is then measured against the target's own mesh")
    if items_default is None:
        return
    p.add_argument("--items", choices=ITEM_MODES, default=items_default,
                   help="how items are written: 'points' (plain meshes under /Root/Items), 'skinned' "
                        "(meshes bound to the target skeleton inside the SkelRoot, weights from the "
                        "K-triangle binding, at most 8 influences), or 'both' (skinned copies named "
                        f"<item>_skinned) (default {items_default})")
    p.add_argument("--no-skin-fit", action="store_true",
                   help="skinned items keep the dressing's rest points as they are; by default their rest "
                        "points are fitted so that the skeleton's linear blend skinning follows the "
                        "per-frame redress over example poses (the package's arm raise, squat, look and "
                        "walk: a few seconds; a tight suit then sinks into the pinched armpits far less)")


def load_target(reference, path, rig: bool | None, pose_align: bool = True):
    """The target of ``path`` ready to dress: read through
    :func:`io.target.read_target`, rigged from ``reference`` when ``rig``
    (None: when it has no skeleton), with a line saying so.

    Returns (Character, fitted reference body points (N_ref, 3) or None).
    """
    from ..fit.rig import rig_from_reference
    from ..io.target import read_target
    from ..progress import info, warn
    target = read_target(path, require_skeleton=False)
    if rig is None:
        rig = target.skeleton is None
    if not rig:
        if target.skeleton is None:
            from ..errors import USDInputError
            raise USDInputError(path, "the target has no skeleton (use --rig-from-reference)")
        return target, None
    why = "has no skeleton" if target.skeleton is None else "--rig-from-reference"
    info(f"{path}: {why}: rigging it from {reference.source} (reference body fitted onto it, skeleton and "
         f"skin weights carried over); items are measured against {path} itself")
    rigged = rig_from_reference(reference, target, {"pose_align": pose_align})
    for w in rigged.fit.warnings:
        warn(w)
    d = rigged.fit.diagnostics
    if "fit_to_target_p99_mm" in d:
        info(f"  fit: fitted->target p99 {d['fit_to_target_p99_mm']:.2f} mm, target->fitted p99 "
             f"{d['target_to_fit_p99_mm']:.2f} mm; {rigged.character.skeleton.n_joints} joints, "
             f"{rigged.character.body.joint_indices.shape[1]} influences per vertex")
    return rigged.character, rigged.fit.points


def output_items(result, target, mode: str, skin_frames=None):
    """The meshes to write for ``mode``: (point items, skinned items) from a
    :class:`dress.apply.DressResult` on ``target``'s bind pose; the skinned
    items' rest points fitted to ``skin_frames``
    (:func:`animate.skin_fit.training_frames`) when given."""
    from ..dress.item_weights import SKINNED_SUFFIX, skinned_items
    points = []
    if mode in ("points", "both"):
        for m in result.items:
            c = m.copy_with_points(m.points)
            c.joint_indices = c.joint_weights = None
            points.append(c)
    skinned = []
    if mode in ("skinned", "both"):
        skinned = skinned_items(result, target, suffix=SKINNED_SUFFIX if mode == "both" else "")
        if skin_frames is not None:
            from ..animate.skin_fit import fit_skinned_items
            from ..dress.item_weights import PIECE_WEIGHT
            from ..dress.plan import group_mask
            # this dressing's rigid pieces (of released parts too) keep their
            # points; their hinges' vertices (on two joints) are fitted
            pl = result.plan
            keep = group_mask(pl.rigid_groups + pl.released_groups, len(pl.ref_points))
            keep &= np.concatenate([np.asarray(m.joint_weights).max(axis=1) for m in skinned]) >= PIECE_WEIGHT
            skinned, _ = fit_skinned_items(skinned, target.body.faces, target.body.points, skin_frames, keep=keep)
    return points, skinned
