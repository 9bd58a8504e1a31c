"""Render speed: frames/s at 640x480 for the dressed reference character.

Rendering only (the scene is read once beforehand): the same Renderer draws
ref_male.usda (body + 5 items, ~52k triangles)

* ``static``: nothing changes between frames (no upload);
* ``buffer update``: every mesh gets new vertices each frame -> normals
  recomputed and the interleaved vertex buffer re-uploaded (glBufferSubData);
* ``rebuild (baseline)``: the same new vertices and normals, but a new
  pyrender Primitive/Mesh is built and uploaded each frame;
* ``trimesh (naive)``: ``pyrender.Mesh.from_trimesh(trimesh.Trimesh(...))``
  per mesh and frame, the usual pyrender idiom;
* ``antialias static``: pyrender's 4x multisampling kept (EGL only);
* ``pyrender PBR shader``: ``Renderer(shading="pbr")``, pyrender's own
  metallic-roughness shader instead of the preview shader of
  :mod:`wearfit_usd.render.shading` (with the fixed program cache);
* ``before``: pyrender's PBR shader *and* its stock ``ShaderProgramCache``,
  whose key never matches under OSMesa (every draw compiles its program
  again): the renderer as it was before the preview shader.

The rebuild/trimesh baselines use the preview shader too, so their ratios
measure only the update strategy.

All in one process, so the ratios compare like with like.
Run alone: ``python3 benchmarks/bench_render.py [--full]`` (writes
benchmarks/results/render.json) or through ``python3 -m benchmarks``.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the checkout importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SIZE = (640, 480)


def _data_dir() -> Path:
    import os
    return Path(os.environ.get("WEARFIT_DATA", REPO.parent / "shared" / "data"))


def _wobble(points: np.ndarray, k: int) -> np.ndarray:
    """A deformed copy (a few mm travelling wave), new array every call."""
    p = points.astype(np.float32, copy=True)
    p[:, 0] += 0.004 * np.sin(10.0 * p[:, 1] + 0.7 * k)
    p[:, 2] += 0.004 * np.cos(8.0 * p[:, 1] + 0.5 * k)
    return p


class _Case:
    """One renderer set up for a case; :meth:`frame` times one frame."""

    def __init__(self, scene, update: str, changing: bool, antialias: bool,
                 shading: str = "preview", stock_cache: bool = False):
        from wearfit_usd.render.camera import frame_box
        from wearfit_usd.render.offscreen import Renderer
        self.changing = changing
        self.trimesh = update == "trimesh"
        base = [m.frames[0] for m in scene.meshes]
        self.poses = [[_wobble(b, k) for b in base] for k in range(4)] if changing else None
        lo, hi = scene.bounds()
        self.r = Renderer(SIZE, update="rebuild" if self.trimesh else update, antialias=antialias,
                          shading=shading)
        if stock_cache:  # pyrender's own cache (misses on every draw under OSMesa)
            self.r._osr._renderer._program_cache = self.r._pr.shader_program.ShaderProgramCache()
        self.hs = [self.r.add_mesh(m.name, b, m.faces, color=m.color)
                   for m, b in zip(scene.meshes, base)]
        self.faces = [m.faces for m in scene.meshes]
        self.colors = [m.color for m in scene.meshes]
        self.nodes = None
        self.r.set_view(frame_box(lo, hi, 28.0, 10.0, SIZE[0] / SIZE[1]))
        self.first = self.r.render()  # warm-up: context, shaders, first upload
        self.i = 0
        self.times: list[float] = []
        self.set_times: list[float] = []

    def frame(self):
        t0 = time.perf_counter()
        if self.trimesh:  # the naive way: a new trimesh -> pyrender.Mesh per mesh and frame
            import trimesh
            pr, sc = self.r._pr, self.r.scene
            if self.nodes is None:
                self.nodes = [e.node for e in self.r._entries]
            pose = self.poses[self.i % len(self.poses)]
            for k, (p, f, c) in enumerate(zip(pose, self.faces, self.colors)):
                sc.remove_node(self.nodes[k])
                mat = pr.MetallicRoughnessMaterial(baseColorFactor=[*map(float, c), 1.0],
                                                   metallicFactor=0.0, doubleSided=True)
                mesh = pr.Mesh.from_trimesh(trimesh.Trimesh(p, f, process=False), material=mat)
                self.nodes[k] = sc.add(mesh)
        elif self.changing:
            pose = self.poses[self.i % len(self.poses)]
            for h, p in zip(self.hs, pose):
                self.r.set_points(h, p.copy())  # a fresh array object, as from a new time code
        t1 = time.perf_counter()
        self.r.render()
        t2 = time.perf_counter()
        self.i += 1
        self.times.append(t2 - t0)
        self.set_times.append(t1 - t0)


def run(full: bool, out_dir: Path) -> list[dict]:
    """Cases run interleaved in blocks (the machine is shared: load hits
    every case alike); frames/s = 1 / median frame time."""
    import os

    from wearfit_usd.render.scene import read_scene
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stage = _data_dir() / "usd" / "ref_male.usda"
    scene = read_scene(stage)
    n = 100 if full else 30
    specs = [  # name, update, changing, antialias, shading, stock cache
        ("static", "buffer", False, False, "preview", False),
        ("buffer update (changing vertices)", "buffer", True, False, "preview", False),
        ("rebuild meshes each frame (baseline)", "rebuild", True, False, "preview", False),
        ("trimesh -> pyrender.Mesh each frame (naive)", "trimesh", True, False, "preview", False),
        ("antialias 4x, static", "buffer", False, True, "preview", False),
        ("static, pyrender PBR shader", "buffer", False, False, "pbr", False),
        ("before: static, PBR + stock shader cache", "buffer", False, False, "pbr", True),
        ("before: buffer update, PBR + stock shader cache", "buffer", True, False, "pbr", True),
    ]
    slow = ("antialias", "before")  # fewer frames per block
    cases = [(name, _Case(scene, *spec)) for name, *spec in specs]
    try:
        from wearfit_usd.render.media import write_png
        write_png(cases[0][1].first, out_dir / "render_ref_male.png")
        load0 = os.getloadavg()[0]
        block = 5
        for _ in range(0, n, block):
            for name, c in cases:
                for _ in range(block if not name.startswith(slow) else 2):
                    c.frame()
        load1 = os.getloadavg()[0]
        rows = []
        for name, c in cases:
            med = float(np.median(c.times))
            rows.append({"case": name, "size": f"{SIZE[0]}x{SIZE[1]}",
                         "triangles": c.r.n_triangles, "frames": len(c.times),
                         "fps": round(1.0 / med, 2), "ms_per_frame_median": round(1000 * med, 2),
                         "ms_per_frame_best": round(1000 * min(c.times), 2),
                         "ms_set_points": round(1000 * float(np.median(c.set_times)), 2),
                         "platform": c.r.platform})
    finally:
        for _, c in cases:
            c.r.close()
    rows.append({"case": "speed-up buffer update vs rebuild",
                 "fps": round(rows[1]["fps"] / rows[2]["fps"], 2),
                 "load_avg_1min": f"{load0:.2f}->{load1:.2f}"})
    rows.append({"case": "speed-up buffer update vs naive trimesh rebuild",
                 "fps": round(rows[1]["fps"] / rows[3]["fps"], 2)})
    rows.append({"case": "speed-up static: preview shader vs pyrender PBR",
                 "fps": round(rows[0]["fps"] / rows[5]["fps"], 2)})
    rows.append({"case": "speed-up static vs before",
                 "fps": round(rows[0]["fps"] / rows[6]["fps"], 2)})
    rows.append({"case": "speed-up buffer update vs before",
                 "fps": round(rows[1]["fps"] / rows[7]["fps"], 2)})
    return rows


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="100 frames per case instead of 30")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    rows = run(args.full, out)
    try:
        from benchmarks import format_table
        print(format_table(rows))
    except Exception:
        for r in rows:
            print(r)
    (out / "render.json").write_text(json.dumps(rows, indent=2, default=float))
    print(f"wrote {out / 'render.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
