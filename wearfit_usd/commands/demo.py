"""`wearfit demo -o DIR`: dress, animate and render the built-in samples."""
from __future__ import annotations


def register(sub, common):
    p = sub.add_parser(
        "demo", parents=[common],
        help="run the whole pipeline on built-in samples (no data needed)",
        description="Make a procedural rigged reference body wearing ten items and four target "
                    "bodies, dress every target, animate packaged BVH clips, render previews and "
                    "write a report. Needs no downloaded data.")
    p.add_argument("-o", "--output", default="demo_out", help="output folder (default demo_out)")
    p.add_argument("--clip", action="append", default=None, metavar="CLIP:TARGET",
                   help="shot to animate, e.g. walk:short_heavy (repeatable; clips: walk, arm_raise, "
                        "squat; targets: tall_thin, short_heavy, broad_shoulders, curvy_remeshed)")
    p.add_argument("--no-render", action="store_true", help="skip previews")
    p.add_argument("--size", default="480x360", help="preview size WxH (default 480x360)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from pathlib import Path

    from ..demo.demo import run_demo
    from ..demo.samples import PRESETS
    from ..demo.samples.motions import CLIPS
    from ..errors import InputError

    shots = None
    if args.clip:
        shots = []
        for spec in args.clip:
            clip, _, target = spec.partition(":")
            target = target or "short_heavy"
            if clip not in CLIPS:
                raise InputError(None, f"--clip: unknown clip {clip!r}; known: {', '.join(CLIPS)}")
            if target not in PRESETS or target == "reference":
                raise InputError(None, f"--clip: unknown target {target!r}; known: "
                                       f"{', '.join(k for k in PRESETS if k != 'reference')}")
            shots.append((clip, target))
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise InputError(None, f"--size: expected WIDTHxHEIGHT, got {args.size!r}") from None
    rep = run_demo(args.output, shots=shots, render=not args.no_render, size=(w, h))
    out = Path(args.output)
    print(f"demo finished in {rep['timings_s']['total']:.1f} s; outputs in {out}/:")
    print(f"  report:        {out / 'report.md'} (and report.json)")
    if "lineup" in rep["files"]:
        print(f"  line-up:       {rep['files']['lineup']}")
    print(f"  samples:       {out / 'samples'}/ (reference.usda + target_*.usda)")
    print(f"  dressed:       {out / 'dressed'}/")
    for s in rep["shots"].values():
        print(f"  shot:          {s['file']}  ({s['frames']} frames, worst-frame new penetration "
              f"{s['worst_frame_new_pen_pct']:.2f} %)")
        if "preview" in s:
            for k in ("gif", "mp4", "contact_sheet"):
                if k in s["preview"]:
                    print(f"    {k + ':':<12} {s['preview'][k]}")
    return 0
