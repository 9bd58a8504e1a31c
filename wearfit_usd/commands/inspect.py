"""`wearfit inspect FILE`: what a USD stage or BVH clip holds."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from .args import bounded_float


def register(sub, common):
    p = sub.add_parser("inspect", parents=[common],
                       help="print skeleton, meshes, skin weights, units and frames of a USD or BVH file",
                       description="Print what a USD stage (skeleton, skinned body, items, skin-weight "
                                   "statistics, up axis, units, time range) or a BVH clip (joints, "
                                   "channels, rotation orders, frames, fps, units) holds.")
    p.add_argument("file", help="a .usd/.usda/.usdc/.usdz stage, a .glb/.gltf character or a .bvh clip")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON instead of text")
    p.add_argument("--joints", action="store_true", help="list every joint")
    p.add_argument("--bvh-scale", type=bounded_float(0.0, 1e3), default=None,
                   help="BVH: metres per file unit (default: detected)")
    p.add_argument("--map", dest="map_other", metavar="OTHER", default=None,
                   help="also print how FILE's joints pair with OTHER's (a USD stage or BVH clip): "
                        "semantic roles found by names and structure, a confidence per role, and the "
                        "joint pairs (FILE is the source, OTHER the target)")
    p.set_defaults(func=run)
    return p


def skin_weight_stats(mesh, n_joints: int) -> dict:
    w = mesh.joint_weights
    ind = mesh.joint_indices
    nz = w > 1e-6
    used = np.zeros(n_joints, dtype=bool)
    used[ind[nz]] = True
    return {
        "element_size": int(w.shape[1]),
        "influences_per_vertex_max": int(nz.sum(axis=1).max()),
        "influences_per_vertex_mean": round(float(nz.sum(axis=1).mean()), 3),
        "joints_with_weights": int(used.sum()),
        "joints_without_weights": int(n_joints - used.sum()),
    }


def describe_usd(path: Path) -> dict:
    from pxr import UsdGeom

    from ..io.gltf import is_gltf
    from ..io.usd import open_stage, read_character
    stage = None if is_gltf(path) else open_stage(path)
    char = read_character(path, require_skeleton=False)
    info = {
        "file": str(path),
        "kind": "gltf" if stage is None else "usd",
        "up_axis": char.up_axis,
        "meters_per_unit": char.meters_per_unit,
        "time_codes_per_second": char.time_codes_per_second if stage is None else stage.GetTimeCodesPerSecond(),
        "frames_per_second": char.time_codes_per_second if stage is None else stage.GetFramesPerSecond(),
        "start_time_code": 0.0 if stage is None else stage.GetStartTimeCode(),
        "end_time_code": 0.0 if stage is None else stage.GetEndTimeCode(),
    }
    lo, hi = char.body.points.min(0), char.body.points.max(0)

    def mesh_info(m):
        return {"name": m.name, "path": m.path, "points": m.n_points,
                "polygons": int(len(m.face_vertex_counts)), "triangles": int(len(m.faces)),
                "skinned": m.is_skinned,
                "primvars": [p.name for p in m.primvars]}

    info["body"] = mesh_info(char.body)
    if len(char.body.parts) > 1:
        info["body"]["parts"] = [{"path": m.path, "points": m.n_points} for m in char.body.parts]
    info["body"]["height_m"] = round(float(hi[1] - lo[1]), 4)
    if char.skeleton is not None:
        sk = char.skeleton
        info["skeleton"] = {"path": sk.path, "joints": sk.n_joints,
                            "roots": [sk.joint_names[j] for j in np.flatnonzero(sk.parents < 0)]}
        if char.body.is_skinned:
            info["body"]["skin_weights"] = skin_weight_stats(char.body, sk.n_joints)
        info["skeleton"]["joint_names"] = sk.joint_names
    else:
        info["skeleton"] = None
    info["items"] = [mesh_info(m) for m in char.items]
    if stage is None:
        from ..io.gltf import animation_names
        info["animations"] = animation_names(path)
        info["meshes_with_time_sampled_points"] = 0
        return info
    anim = [str(p.GetPath()) for p in stage.Traverse() if p.GetTypeName() == "SkelAnimation"]
    info["animations"] = anim
    timesampled = 0
    for p in stage.Traverse():
        if p.IsA(UsdGeom.Mesh):
            timesampled += UsdGeom.Mesh(p).GetPointsAttr().GetNumTimeSamples() > 1
    info["meshes_with_time_sampled_points"] = int(timesampled)
    return info


def describe_bvh(path: Path, scale) -> dict:
    from ..io.bvh import read_bvh
    motion = read_bvh(path, scale=scale)
    return motion.summary()


def skeleton_of(path: Path, scale=None):
    """(names, parents (J,), rest positions (J, 3)) of a USD stage's skeleton
    (bind pose) or a BVH clip (rest pose). Raises :class:`InputError` without one."""
    if path.suffix.lower() == ".bvh":
        from ..io.bvh import read_bvh
        m = read_bvh(path, scale=scale)
        return m.joint_names, m.parents, m.rest_global_transforms()[:, 3, :3]
    from ..io.usd import read_character
    char = read_character(path, require_skeleton=False)
    if char.skeleton is None:
        raise InputError(path, "no skeleton to pair")
    sk = char.skeleton
    return sk.joint_names, sk.parents, sk.bind_positions()


def describe_pairing(path: Path, other: Path, scale=None) -> dict:
    """The pairing of FILE's skeleton (source) with OTHER's (target):
    :meth:`wearfit_usd.motion.rig_match.RigMatch.report` plus each side's roles."""
    from ..motion.rig_match import match_skeletons
    if not other.exists():
        raise InputError(other, "file not found")
    sn, sp, spos = skeleton_of(path, scale)
    tn, tp, tpos = skeleton_of(other, scale)
    m = match_skeletons(sn, sp, spos, tn, tp, tpos)
    rep = m.report()
    rep["source"] = {"file": str(path), **m.source.report()}
    rep["target"] = {"file": str(other), **m.target.report()}
    return rep


def format_pairing(rep: dict) -> str:
    """Text of :func:`describe_pairing`: roles found on both sides (and every
    key role), confidences, the other pairs and the structure's notes."""
    from ..motion.rig_match import KEY_ROLES
    src, tgt = rep["source"], rep["target"]
    lines = [f"pairing {src['file']} (source) -> {tgt['file']} (target): {rep['mapped']} joints paired, "
             f"confidence {rep['confidence']:.2f}"
             + (" (by names)" if rep["by_names"] else " (roles from structure and names)")]
    miss = rep["missing_key_roles"]
    if miss["source"] or miss["target"]:
        lines.append("  KEY ROLES NOT PAIRED: " + "; ".join(
            f"{k} lacks {', '.join(v)}" for k, v in miss.items() if v))
    lines.append(f"  {'role':<14} {'source':<28} {'conf':>5}  {'target':<28} {'conf':>5}")
    for role, (a, b) in rep["roles"].items():
        if not (a and b) and role not in KEY_ROLES:
            continue
        ca = src["confidence"].get(role)
        cb = tgt["confidence"].get(role)
        lines.append(f"  {role:<14} {a or '-':<28} {'' if ca is None else f'{ca:.2f}':>5}  "
                     f"{b or '-':<28} {'' if cb is None else f'{cb:.2f}':>5}")
    role_joints = {b for a, b in rep["roles"].values() if b}
    extra = [(t, s) for t, s in rep["pairs"].items() if t not in role_joints]
    if extra:
        lines.append(f"  other pairs ({len(extra)}): " + ", ".join(f"{s}->{t}" for t, s in extra))
    for side in (src, tgt):
        for n in side["notes"]:
            lines.append(f"  note ({side['file']}): {n}")
    return "\n".join(lines)


def format_text(info: dict, all_joints: bool) -> str:
    lines = [f"{info['file']}"]
    if info["kind"] == "bvh":
        for k, v in info.items():
            if k in ("file", "kind", "joint_names"):
                continue
            lines.append(f"  {k}: {v}")
        names = info.get("joint_names", [])
        lines.append(f"  joints ({len(names)}): " + (", ".join(names) if all_joints else
                                                     ", ".join(names[:12]) + (" ..." if len(names) > 12 else "")))
        return "\n".join(lines)
    lines.append(f"  up axis {info['up_axis']}, {info['meters_per_unit']} m/unit, "
                 f"{info['time_codes_per_second']} time codes/s, "
                 f"time {info['start_time_code']}..{info['end_time_code']}")
    b = info["body"]
    lines.append(f"  body {b['path']}: {b['points']} points, {b['polygons']} polygons "
                 f"({b['triangles']} triangles), height {b['height_m']} m, "
                 f"{'skinned' if b['skinned'] else 'NOT skinned'}")
    if b.get("parts"):
        lines.append(f"    made of {len(b['parts'])} skinned meshes (merged for fitting, written apart): "
                     + ", ".join(p["path"] for p in b["parts"][:8])
                     + (" ..." if len(b["parts"]) > 8 else ""))
    if "skin_weights" in b:
        s = b["skin_weights"]
        lines.append(f"    skin weights: elementSize {s['element_size']}, influences/vertex "
                     f"max {s['influences_per_vertex_max']} mean {s['influences_per_vertex_mean']}, "
                     f"{s['joints_with_weights']} joints weighted, {s['joints_without_weights']} unweighted")
    sk = info["skeleton"]
    if sk:
        names = sk["joint_names"]
        lines.append(f"  skeleton {sk['path']}: {sk['joints']} joints, root {', '.join(sk['roots'])}")
        lines.append("    joints: " + (", ".join(names) if all_joints else
                                         ", ".join(names[:12]) + (" ..." if len(names) > 12 else "")))
    else:
        lines.append("  skeleton: none")
    lines.append(f"  items ({len(info['items'])}):")
    for m in info["items"]:
        lines.append(f"    {m['name']:<28} {m['points']:>7} points {m['polygons']:>7} polygons"
                     f"{'  skinned' if m['skinned'] else ''}  {m['path']}")
    if info["animations"]:
        lines.append(f"  animations: {', '.join(info['animations'])}")
    if info["meshes_with_time_sampled_points"]:
        lines.append(f"  meshes with time-sampled points: {info['meshes_with_time_sampled_points']}")
    return "\n".join(lines)


def run(args) -> int:
    path = Path(args.file)
    if not path.exists():
        raise InputError(path, "file not found")
    if path.suffix.lower() == ".bvh":
        info = describe_bvh(path, args.bvh_scale)
    elif path.suffix.lower() in (".usd", ".usda", ".usdc", ".usdz", ".glb", ".gltf"):
        info = describe_usd(path)
    else:
        raise InputError(path, "unknown file type (expected .usd, .usda, .usdc, .usdz, .glb, .gltf or .bvh)")
    pairing = describe_pairing(path, Path(args.map_other), args.bvh_scale) if args.map_other else None
    if args.json:
        if pairing is not None:
            info["pairing"] = pairing
        print(json.dumps(info, indent=2, default=float))
    else:
        print(format_text(info, args.joints))
        if pairing is not None:
            print(format_pairing(pairing))
    return 0
