"""`wearfit render SCENE.usd -o DIR`: offscreen previews (PNG, contact sheet, GIF, MP4, fit maps)."""
from __future__ import annotations

from ..errors import InputError
from .args import FPS_MAX, bounded_float


def register(sub, common):
    import argparse
    p = sub.add_parser(
        "render", parents=[common],
        help="render a USD stage offscreen to PNG frames, a contact sheet, GIF or MP4",
        description="Render a USD stage (skinned meshes posed through UsdSkel at each time code, "
                    "time-sampled points) without GPU or display: one PNG per frame "
                    "(DIR/frame_0000.png ...) and DIR/contact_sheet.png, optionally "
                    "DIR/preview.gif and DIR/preview.mp4. The camera frames the character over "
                    "all rendered frames, or follows it when it travels (see --track).")
    p.add_argument("scene", help="a .usd/.usda/.usdc/.usdz stage or a .glb/.gltf file")
    p.add_argument("-o", "--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--frames", metavar="A:B", default=None,
                   help="time codes to render, inclusive (A:B, A:, :B or A); default the "
                        "stage's whole range")
    p.add_argument("--size", default="640x480", metavar="WxH", help="image size (default 640x480)")
    p.add_argument("--camera", default="auto", metavar="VIEW",
                   help="front, side, back, auto (three-quarter) or turntable:N (N views around "
                        "the first frame); default auto")
    p.add_argument("--track", action=argparse.BooleanOptionalAction, default=None,
                   help="camera follows the character (fixed orientation and distance, smoothed "
                        "horizontal path, fixed height); default: only when its horizontal travel "
                        "exceeds half its height; never for turntables")
    p.add_argument("--gif", action="store_true", help="also write DIR/preview.gif")
    p.add_argument("--mp4", action="store_true", help="also write DIR/preview.mp4 (H.264)")
    p.add_argument("--heatmap", action="store_true",
                   help="colour items by clearance to the body (fit map with legend)")
    p.add_argument("--heatmap-against", metavar="REFERENCE.usd", default=None,
                   help="colour items by change of clearance versus the same items in REFERENCE")
    p.add_argument("--fps", type=bounded_float(0.0, FPS_MAX), default=None,
                   help="GIF/MP4 frame rate (default: the stage's time codes per second; "
                        "turntables 12)")
    p.add_argument("--antialias", action="store_true",
                   help="4x multisampling (EGL only; slower in software rendering)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from pathlib import Path

    from ..progress import info, verbosity
    from ..render.preview import render_to_dir
    scene = Path(args.scene)
    if not scene.exists():
        raise InputError(scene, "file not found")
    if args.heatmap_against is not None and not Path(args.heatmap_against).exists():
        raise InputError(args.heatmap_against, "file not found")
    out = render_to_dir(scene, Path(args.out), frames=args.frames, size=args.size,
                        camera=args.camera, gif=args.gif, mp4=args.mp4,
                        heatmap=args.heatmap or args.heatmap_against is not None,
                        heatmap_against=args.heatmap_against, fps=args.fps,
                        antialias=args.antialias, show_progress=verbosity() >= 1,
                        track=args.track)
    info(f"wrote {out['n_frames']} frame(s) to {args.out}/frame_*.png and contact_sheet.png"
         + (" (camera tracking the character)" if out.get("tracked") else "")
         + (f", {out['gif']}" if "gif" in out else "") + (f", {out['mp4']}" if "mp4" in out else ""))
    return 0
