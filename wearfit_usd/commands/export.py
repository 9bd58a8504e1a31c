"""`wearfit export SCENE -o character.glb`: a dressed or animated scene as glTF 2.0 binary."""
from __future__ import annotations

from .args import bounded_int, check_inputs, check_output


def register(sub, common):
    p = sub.add_parser("export", parents=[common],
                       help="write a dressed or animated scene as glTF 2.0 binary (.glb)",
                       description="Write the output of `wearfit dress`, `animate` or `fit` as a glTF 2.0 "
                                   "binary: the body and items with their materials (baseColor from the "
                                   "UsdPreviewSurface, textures when the asset has them), the skeleton and "
                                   "the animation, in glTF's conventions (metres, Y up, +Z forward). "
                                   "Skinned items stay skinned; items that are only point caches become "
                                   "static meshes at the first frame with one morph target per frame.")
    p.add_argument("scene", help="a wearfit scene (.usd/.usda/.usdc)")
    p.add_argument("-o", "--output", required=True, help="output .glb")
    p.add_argument("--morph-every", type=bounded_int(1), default=1, metavar="N",
                   help="point-cache items: one morph target every N frames (in between, glTF viewers "
                        "blend linearly); default 1")
    p.add_argument("--max-frames", type=bounded_int(1), default=None, metavar="N",
                   help="export only the first N frames of an animated scene")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..io.gltf_write import export_scene
    from ..progress import info
    check_inputs(args.scene)
    out = check_output(args.output, (args.scene,), suffixes=(".glb",))
    rep = export_scene(args.scene, out, morph_every=args.morph_every, max_frames=args.max_frames)
    info(f"wrote {out}: {rep['size_bytes'] / 1e6:.2f} MB, {rep['meshes']} meshes "
         f"({rep['skinned']} skinned, {rep['morphed']} with {rep['morph_targets']} morph targets), "
         f"{rep['joints']} joints, {rep['frames']} frames, {rep['materials']} materials, "
         f"{rep['textures']} textures")
    return 0
