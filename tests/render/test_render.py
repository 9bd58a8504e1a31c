"""Offscreen previews: real data, assertions on pixels."""
from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

SIZE = (320, 240)
BG = np.array([0.94, 0.94, 0.95]) * 255


def _foreground(img: np.ndarray) -> np.ndarray:
    return np.abs(img.astype(float) - BG).max(axis=2) > 12


def _chroma_hits(img: np.ndarray, color, tol=0.035, min_brightness=25) -> int:
    """Pixels whose chromaticity (rgb / sum) is close to ``color``'s."""
    px = img.reshape(-1, 3).astype(float)
    s = px.sum(axis=1)
    ok = s > 3 * min_brightness
    chroma = px[ok] / s[ok, None]
    c = np.asarray(color, float)
    c = c / c.sum()
    return int((np.abs(chroma - c).max(axis=1) < tol).sum())


@pytest.fixture(scope="module")
def male_scene(usd_dir):
    from wearfit_usd.render.scene import read_scene
    return read_scene(usd_dir / "ref_male.usda")


@pytest.fixture(scope="module")
def male_views(male_scene):
    from wearfit_usd.render.preview import render_scene
    out = {}
    for cam in ("front", "side"):
        out[cam] = render_scene(male_scene, size=SIZE, camera=cam, show_progress=False)[0]
    return out


def test_scene_reads_zup_stage_into_yup_metres(male_scene):
    assert male_scene.up_axis == "Z"
    body = male_scene.body
    assert body is not None and body.skinned and body.name == "Body"
    lo, hi = body.frames[0].min(0), body.frames[0].max(0)
    height = hi[1] - lo[1]
    assert 1.5 < height < 2.0, height  # Y up, metres
    names = {m.name for m in male_scene.items}
    assert {"male_casualsuit01", "shoes01", "fedora01"} <= names
    colors = [tuple(m.color) for m in male_scene.meshes]
    assert len(set(colors)) == len(colors), "body and items need distinct colours"


def test_character_framed_and_centred(male_views):
    for cam, img in male_views.items():
        assert img.shape == (SIZE[1], SIZE[0], 3) and img.dtype == np.uint8
        ys, xs = np.nonzero(_foreground(img))
        assert len(ys) > 0.04 * img.shape[0] * img.shape[1], cam
        # in frame: not touching the borders, tall, centred
        assert ys.min() > 0 and ys.max() < img.shape[0] - 1 and xs.min() > 0 and xs.max() < img.shape[1] - 1
        assert (ys.max() - ys.min()) > 0.7 * img.shape[0], cam
        cy, cx = (ys.min() + ys.max()) / 2, (xs.min() + xs.max()) / 2
        assert abs(cy - img.shape[0] / 2) < 0.1 * img.shape[0], (cam, cy)
        assert abs(cx - img.shape[1] / 2) < 0.1 * img.shape[1], (cam, cx)
        # lit: not flat; shading varies over the figure
        assert img[ys, xs].astype(float).std() > 15


def test_items_visible_in_their_colours(male_scene, male_views):
    img = male_views["front"]
    hits = {m.name: _chroma_hits(img, m.color) for m in male_scene.meshes}
    assert hits["male_casualsuit01"] > 2000, hits
    assert hits["Body"] > 200, hits          # face and hands
    assert hits["fedora01"] > 20, hits
    assert hits["shoes01"] > 20, hits


def test_front_and_side_differ(male_views):
    a, b = male_views["front"].astype(float), male_views["side"].astype(float)
    assert np.abs(a - b).mean() > 3.0
    # the side silhouette is much narrower than the front one (arms out)
    wa = np.ptp(np.nonzero(_foreground(male_views["front"]))[1])
    wb = np.ptp(np.nonzero(_foreground(male_views["side"]))[1])
    assert wb < 0.75 * wa, (wa, wb)


# --------------------------------------------------------------------------
# synthetic stages


def _cube(size=1.0):
    import trimesh
    m = trimesh.creation.box(extents=(size, size, size))
    return np.asarray(m.vertices), np.asarray(m.faces)


def _write_animated(path):
    """3 frames: a skinned box whose joint swings (SkelAnimation) and a
    plain box with time-sampled points."""
    from pxr import Gf, Usd, UsdGeom, UsdSkel, Vt
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(2)
    stage.SetTimeCodesPerSecond(24)
    UsdGeom.Xform.Define(stage, "/World")
    UsdSkel.Root.Define(stage, "/World/Char")
    skel = UsdSkel.Skeleton.Define(stage, "/World/Char/Skel")
    joints = ["root", "root/arm"]
    skel.CreateJointsAttr(joints)
    rest = [Gf.Matrix4d(1.0), Gf.Matrix4d(1.0).SetTranslate(Gf.Vec3d(0, 1, 0))]
    bind = [Gf.Matrix4d(1.0), Gf.Matrix4d(1.0).SetTranslate(Gf.Vec3d(0, 1, 0))]
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray(bind))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray(rest))
    anim = UsdSkel.Animation.Define(stage, "/World/Char/Anim")
    anim.CreateJointsAttr(joints)
    anim.CreateTranslationsAttr().Set(Vt.Vec3fArray([(0, 0, 0), (0, 1, 0)]))
    anim.CreateScalesAttr().Set(Vt.Vec3hArray([(1, 1, 1), (1, 1, 1)]))
    rot = anim.CreateRotationsAttr()
    for t, deg in ((0, 0.0), (1, 45.0), (2, 90.0)):
        q = Gf.Rotation(Gf.Vec3d(0, 0, 1), deg).GetQuat()
        rot.Set(Vt.QuatfArray([Gf.Quatf(1, 0, 0, 0), Gf.Quatf(q)]), t)
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    pts, faces = _cube(0.5)
    pts = pts + np.array([0, 1.5, 0])  # around the arm joint's child end
    mesh = UsdGeom.Mesh.Define(stage, "/World/Char/ArmMesh")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr([3] * len(faces))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.ravel().astype(np.int32)))
    b = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    b.CreateSkeletonRel().SetTargets([skel.GetPath()])
    b.CreateJointIndicesPrimvar(False, 1).Set(Vt.IntArray([1] * len(pts)))
    b.CreateJointWeightsPrimvar(False, 1).Set(Vt.FloatArray([1.0] * len(pts)))
    b.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
    box = UsdGeom.Mesh.Define(stage, "/World/Box")
    bp, bf = _cube(0.3)
    box.CreateFaceVertexCountsAttr([3] * len(bf))
    box.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(bf.ravel().astype(np.int32)))
    box.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([(0.1, 0.8, 0.2)])
    for t in range(3):
        box.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy((bp + [0.8 + 0.3 * t, 0.2, 0]).astype(np.float32)), t)
    stage.GetRootLayer().Save()
    return path


@pytest.fixture(scope="module")
def animated_stage(tmp_path_factory):
    return _write_animated(tmp_path_factory.mktemp("anim") / "anim.usda")


def test_animated_stage_frames_differ(animated_stage):
    from wearfit_usd.render.preview import render_scene
    from wearfit_usd.render.scene import read_scene
    scene = read_scene(animated_stage)
    assert scene.times == [0.0, 1.0, 2.0]
    arm = next(m for m in scene.meshes if m.name == "ArmMesh")
    box = next(m for m in scene.meshes if m.name == "Box")
    assert arm.skinned and arm.animated and box.animated
    # UsdSkel posed the arm: 90 degrees about Z around (0, 1, 0) takes the
    # box centre (0, 1.5, 0) to (-0.5, 1, 0)
    assert np.allclose(arm.frames[2].mean(0), [-0.5, 1.0, 0.0], atol=1e-4)
    assert np.allclose(box.color, [0.1, 0.8, 0.2])  # authored displayColor
    imgs = render_scene(scene, size=(160, 120), camera="front", show_progress=False)
    assert len(imgs) == 3
    d = np.abs(imgs[2].astype(float) - imgs[0].astype(float)).mean()
    assert d > 2.0, d
    px = imgs[0].reshape(-1, 3).astype(int)
    green = (px[:, 1] > px[:, 0] + 60) & (px[:, 1] > px[:, 2] + 60)
    assert green.sum() > 30, green.sum()


def test_gif_and_mp4_written_and_readable(animated_stage, tmp_path):
    import imageio.v3 as iio

    from wearfit_usd.render.preview import render_to_dir
    out = tmp_path / "out"
    res = render_to_dir(animated_stage, out, size=(160, 120), gif=True, mp4=True,
                        show_progress=False)
    assert [p.name for p in res["frames"]] == ["frame_0000.png", "frame_0001.png", "frame_0002.png"]
    assert (out / "contact_sheet.png").exists()
    gif = iio.imread(out / "preview.gif", index=None)
    assert gif.shape[0] == 3
    frames = list(iio.imiter(out / "preview.mp4", plugin="pyav") if _has_pyav() else
                  _read_mp4_frames(out / "preview.mp4"))
    assert len(frames) == 3
    assert frames[0].shape[:2] == (120, 160)
    assert not [p for p in out.iterdir() if p.name.startswith(".")], "temporary files left"


def _has_pyav():
    import importlib.util
    return importlib.util.find_spec("av") is not None


def _read_mp4_frames(path):
    import imageio.v2 as imageio
    r = imageio.get_reader(str(path), format="FFMPEG")
    try:
        return [f for f in r]
    finally:
        r.close()


def test_turntable_gives_n_views(animated_stage):
    from wearfit_usd.render.preview import render_frames
    imgs = render_frames(animated_stage, size=(96, 72), camera="turntable:4", show_progress=False)
    assert len(imgs) == 4
    assert np.abs(imgs[0].astype(float) - imgs[1].astype(float)).mean() > 1.0


# --------------------------------------------------------------------------
# camera tracking


def _write_walker(path, travel=3.0, n=10, static=False):
    """A 'character' (0.5 x 1.7 x 0.3 m box standing on the ground) whose
    time-sampled points move ``travel`` metres along +x over ``n`` frames
    (10 time codes per second) with a 5 cm side-to-side sway;
    ``static``: one unanimated pose."""
    import trimesh
    from pxr import Usd, UsdGeom, Vt
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(10)
    box = trimesh.creation.box(extents=(0.5, 1.7, 0.3))
    pts, faces = np.asarray(box.vertices) + [0, 0.85, 0], np.asarray(box.faces)
    mesh = UsdGeom.Mesh.Define(stage, "/Walker")
    mesh.CreateFaceVertexCountsAttr([3] * len(faces))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.ravel().astype(np.int32)))
    if static:
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    else:
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(n - 1)
        for t in range(n):
            shift = [travel * t / (n - 1), 0, 0.05 * np.sin(np.pi * t / 2)]
            mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy((pts + shift).astype(np.float32)), t)
    stage.GetRootLayer().Save()
    return path


def _fg_box(img):
    ys, xs = np.nonzero(_foreground(img))
    assert len(ys), "nothing drawn"
    return ys.min(), ys.max(), xs.min(), xs.max()


@pytest.fixture(scope="module")
def walker_renders(tmp_path_factory):
    from wearfit_usd.render.preview import render_to_dir
    base = tmp_path_factory.mktemp("walker")
    path = _write_walker(base / "walker.usda")
    import imageio.v3 as iio
    out = {}
    for name, track in (("auto", None), ("off", False), ("on", True)):
        res = render_to_dir(path, base / name, size=SIZE, track=track, show_progress=False)
        out[name] = (res["tracked"], [iio.imread(p)[..., :3] for p in res["frames"]])
    return out


def test_tracking_keeps_walker_centred_and_same_size(walker_renders):
    tracked, imgs = walker_renders["auto"]
    assert tracked, "3 m travel for a 1.7 m character must track automatically"
    assert len(imgs) == 10
    h, w = imgs[0].shape[:2]
    heights = []
    for i, img in enumerate(imgs):
        y0, y1, x0, x1 = _fg_box(img)
        assert y0 > 0 and x0 > 0 and y1 < h - 1 and x1 < w - 1, (i, "cut off")
        assert abs((x0 + x1) / 2 - w / 2) < 0.1 * w, (i, x0, x1)
        assert abs((y0 + y1) / 2 - h / 2) < 0.1 * h, (i, y0, y1)
        heights.append(y1 - y0)
        assert y1 - y0 > 0.6 * h, (i, "character too small")
    assert max(heights) < 1.15 * min(heights), heights
    # explicit track=True is the same camera
    assert all(np.array_equal(a, b) for a, b in zip(imgs, walker_renders["on"][1]))


def test_no_tracking_walker_moves_across_fixed_frame(walker_renders):
    tracked, imgs = walker_renders["off"]
    assert not tracked
    w = imgs[0].shape[1]
    boxes = [_fg_box(img) for img in imgs]
    cx = [(b[2] + b[3]) / 2 for b in boxes]
    assert cx[-1] - cx[0] > 0.4 * w, cx               # walks from left to right
    assert all(b - a > 0 for a, b in zip(cx, cx[1:])), cx
    # framing the whole path: the character is much smaller than when tracked
    tracked_h = np.mean([b[1] - b[0] for b in map(_fg_box, walker_renders["auto"][1])])
    assert max(b[1] - b[0] for b in boxes) < 0.8 * tracked_h


def test_tracking_off_for_static_and_in_place_motion(tmp_path, animated_stage):
    from wearfit_usd.render.preview import render_frames, render_to_dir, resolve_track
    from wearfit_usd.render.scene import read_scene
    static = _write_walker(tmp_path / "static.usda", static=True)
    res = render_to_dir(static, tmp_path / "s", size=(96, 72), show_progress=False)
    assert res["tracked"] is False and res["n_frames"] == 1
    # small travel (0.5 m for a 1.7 m character) and the swinging-arm stage: no tracking
    small = read_scene(_write_walker(tmp_path / "small.usda", travel=0.5))
    assert resolve_track(small) is False
    assert resolve_track(read_scene(animated_stage)) is False
    # ... unless asked; never for turntables
    assert resolve_track(small, track=True) is True
    walker = read_scene(_write_walker(tmp_path / "w.usda"))
    assert resolve_track(walker, camera="turntable:4") is False
    assert resolve_track(walker, camera="side", track=False) is False
    # a turntable of the walker renders its first frame around the character as before
    a = render_frames(tmp_path / "w.usda", size=(96, 72), camera="turntable:2", show_progress=False)
    b = render_frames(tmp_path / "w.usda", size=(96, 72), camera="turntable:2", track=True,
                      show_progress=False)
    assert len(a) == 2 and all(np.array_equal(x, y) for x, y in zip(a, b))


def test_smooth_path_no_lag_and_no_jitter():
    from wearfit_usd.render.camera import smooth_path, tracking_views
    t = np.arange(60.0)
    line = np.stack([0.05 * t, 1.0 - 0.02 * t], axis=1)
    # a steady walk comes back unchanged, ends included (no lag, no stop)
    assert np.allclose(smooth_path(t, line, sigma=12.0), line, atol=1e-9)
    # step-frequency sway (period 15 frames, 5 cm) is mostly removed
    sway = line + 0.05 * np.sin(2 * np.pi * t / 15)[:, None]
    sm = smooth_path(t, sway, sigma=12.0)
    err = np.abs(sm - line)
    assert err[20:40].max() < 0.002, err[20:40].max()     # away from the ends: gone
    assert err.max() < 0.025, err.max()                    # ends: under half the sway
    steps = np.diff(sm, axis=0)                            # raw steps vary 0.029..0.071
    assert np.abs(steps[:, 0] - 0.05).max() < 0.005, steps[:, 0]  # camera moves steadily
    # views: same orientation and distance, ground height fixed, targets on the path
    los = np.column_stack([sway[:, 0] - 0.3, np.zeros(60), sway[:, 1] - 0.2])
    his = los + [0.6, 1.8, 0.4]
    views = tracking_views(los, his, t, 28.0, 10.0, 4 / 3, sigma=12.0)
    offs = np.array([v.eye - v.target for v in views])
    assert np.allclose(offs, offs[0])
    assert np.allclose([v.eye[1] for v in views], views[0].eye[1])
    shift = np.array([v.target for v in views])[:, [0, 2]] - sm   # targets on the smoothed path
    assert np.allclose(shift, shift[0]) and np.abs(shift[0]).max() < 0.05, shift[0]


# --------------------------------------------------------------------------
# heatmap


def _write_sphere_shell(path, units_per_metre=100.0):
    """Z-up stage in centimetres: a sphere body (r 0.3 m) and a shell
    (r 0.33 m) shifted +3 cm along x: ~6 cm clearance on +x, ~0 on -x."""
    import trimesh
    from pxr import Usd, UsdGeom, Vt
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0 / units_per_metre)
    body = trimesh.creation.icosphere(subdivisions=4, radius=0.30)
    shell = trimesh.creation.icosphere(subdivisions=3, radius=0.33)
    for name, m, shift in (("Body", body, 0.0), ("Shell", shell, 0.03)):
        g = UsdGeom.Mesh.Define(stage, f"/{name}")
        pts = (np.asarray(m.vertices) + [shift, 0, 0]) * units_per_metre
        g.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
        g.CreateFaceVertexCountsAttr([3] * len(m.faces))
        g.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(m.faces).ravel().astype(np.int32)))
    stage.GetRootLayer().Save()
    return path


def test_heatmap_colours_follow_clearance(tmp_path):
    from wearfit_usd.render.heatmap import colormap
    from wearfit_usd.render.preview import render_frames
    path = _write_sphere_shell(tmp_path / "shell.usda")
    w, h = 320, 240
    img = render_frames(path, size=(w, h), camera="front", heatmap=True, show_progress=False)[0]
    mid = img[int(h * 0.4):int(h * 0.6)].astype(float)
    left = mid[:, int(w * 0.22):int(w * 0.36)].reshape(-1, 3)   # -x side: tight
    right = mid[:, int(w * 0.60):int(w * 0.72)].reshape(-1, 3)  # +x side: loose
    fg_l = left[np.abs(left - BG).max(1) > 12]
    fg_r = right[np.abs(right - BG).max(1) > 12]
    assert len(fg_l) > 50 and len(fg_r) > 50
    lm, r = fg_l.mean(0), fg_r.mean(0)
    assert lm[0] > lm[2] + 40, lm   # red dominates where the shell touches
    assert r[2] > r[0] + 40, r   # blue dominates where it is ~6 cm away
    # the colour map itself: tight -> red, loose -> blue
    tight, loose = colormap(np.array([0.0, 0.06]))
    assert tight[0] > 0.8 and loose[2] > 0.8
    # legend drawn at the right edge
    strip = img[int(h * 0.3):int(h * 0.7), w - 45:w - 30].astype(float)
    assert (np.abs(strip - BG).max(axis=2) > 40).mean() > 0.3


def test_heatmap_against_reference_is_neutral_for_itself(tmp_path):
    from wearfit_usd.render.preview import render_frames
    path = _write_sphere_shell(tmp_path / "shell.usda")
    img = render_frames(path, size=(160, 120), camera="front", heatmap_against=path,
                        show_progress=False)[0]
    centre = img[50:70, 60:90].reshape(-1, 3).astype(float)
    # zero change everywhere -> neutral grey, no strong hue
    assert (centre.max(1) - centre.min(1)).mean() < 25


# --------------------------------------------------------------------------
# bad input


def test_errors_empty_stage_missing_file_and_bad_frames(tmp_path, animated_stage):
    from pxr import Usd, UsdGeom

    from wearfit_usd.cli import main
    from wearfit_usd.errors import InputError
    from wearfit_usd.render.preview import render_frames
    empty = tmp_path / "empty.usda"
    st = Usd.Stage.CreateNew(str(empty))
    UsdGeom.Xform.Define(st, "/Root")
    st.GetRootLayer().Save()
    with pytest.raises(InputError, match="no visible Mesh"):
        render_frames(empty, show_progress=False)
    with pytest.raises(InputError, match="not found"):
        render_frames(tmp_path / "nope.usda", show_progress=False)
    with pytest.raises(InputError, match="outside the stage's time range"):
        render_frames(animated_stage, frames="0:7", show_progress=False)
    out = tmp_path / "out"
    assert main(["render", str(animated_stage), "-o", str(out), "--frames", "5:6", "-q"]) == 2
    assert not out.exists() or not any(out.iterdir())
    assert main(["render", str(empty), "-o", str(out), "-q"]) == 2
    assert main(["render", str(animated_stage), "-o", str(out), "--camera", "top", "-q"]) == 2
    assert not out.exists() or not any(out.iterdir())


# --------------------------------------------------------------------------
# shading (wearfit_usd.render.shading)


def _render_both(scene, yaw=0.0, frames=1):
    """{shading: (image, renderer program-cache keys)} for one view of ``scene``."""
    from wearfit_usd.render.camera import frame_box
    from wearfit_usd.render.offscreen import Renderer
    lo, hi = scene.bounds()
    out = {}
    for shading in ("preview", "pbr"):
        with Renderer(SIZE, shading=shading) as r:
            for m in scene.meshes:
                r.add_mesh(m.name, m.frames[0], m.faces, color=m.color)
            r.set_view(frame_box(lo, hi, yaw, 10.0, SIZE[0] / SIZE[1]))
            imgs = [r.render() for _ in range(frames)]
            out[shading] = (imgs, list(r._osr._renderer._program_cache._program_cache))
    return out


def test_program_cache_hits_and_preview_shader_close_to_pbr(male_scene):
    res = _render_both(male_scene, frames=3)
    for shading, (imgs, keys) in res.items():
        # one lit program for all six meshes and all frames (pyrender's own cache
        # keyed on OSMesa's context pointer and compiled a program per draw)
        assert len(keys) == 1, (shading, keys)
        assert keys[0][0] is (shading == "preview"), keys  # the preview program is the one used
        assert np.array_equal(imgs[0], imgs[2])
    prev, pbr = res["preview"][0][0].astype(float), res["pbr"][0][0].astype(float)
    fg = _foreground(res["pbr"][0][0])
    diff = np.abs(prev - pbr)[fg]
    # a different shader: not identical ...
    assert diff.mean() > 1.0
    # ... but the same look: same rig, colours and exposure (measured mean 6.6 / 255)
    assert diff.mean() < 15.0, diff.mean()
    assert abs(prev[fg].mean() - pbr[fg].mean()) < 15.0


def test_back_faces_lit():
    """A double-sided sheet seen from behind is shaded with the flipped normal,
    as bright as from the front (the lights follow the camera)."""
    from wearfit_usd.render.camera import frame_box
    from wearfit_usd.render.offscreen import Renderer
    pts = np.array([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [0.5, 1.0, 0.0], [-0.5, 1.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])  # normal +Z
    lo, hi = pts.min(0) - [0, 0, 0.1], pts.max(0) + [0, 0, 0.1]
    means = []
    with Renderer((96, 96), background=(0.0, 0.0, 0.0)) as r:
        r.add_mesh("sheet", pts, faces, color=(0.6, 0.6, 0.6))
        for yaw in (0.0, 180.0):
            r.set_view(frame_box(lo, hi, yaw, 0.0, 1.0))
            img = r.render().astype(float)
            fg = img.max(axis=2) > 5
            assert fg.mean() > 0.2, yaw
            means.append(img[fg].mean())
    assert min(means) > 60, means
    assert abs(means[0] - means[1]) < 0.15 * max(means), means


def test_tight_items_drawn_proud_of_the_skin(usd_dir):
    """ref_female's suit is tight and low-poly: drawn at its true position the
    skin bulges through between its vertices; the display offset hides that
    (fewer skin-coloured pixels), while the body outside the suit stays."""
    from wearfit_usd.render.preview import render_scene
    from wearfit_usd.render.scene import read_scene
    scene = read_scene(usd_dir / "ref_female.usda", None)
    exact = render_scene(scene, size=(240, 360), camera="front", show_progress=False, item_offset=0.0)[0]
    proud = render_scene(scene, size=(240, 360), camera="front", show_progress=False)[0]
    body = next(m for m in scene.meshes if m.role == "body")
    skin = (np.asarray(body.color) * 255).astype(float)

    def skin_pixels(img):
        return int((np.abs(img.astype(float) - skin).max(axis=2) < 40).sum())

    assert skin_pixels(proud) < 0.7 * skin_pixels(exact)
    assert skin_pixels(proud) > 500  # face, arms and hands still show


def test_interrupted_write_leaves_no_folder_it_made(tmp_path, monkeypatch):
    """A write stopped part way (Ctrl-C, SIGTERM, a full disk) removes its
    temporary frames and the output folder it created, and keeps a folder
    that was there before."""
    from wearfit_usd.render import media

    def fail(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(media, "write_png", fail)
    images = [np.zeros((8, 8, 3), np.uint8)] * 3
    out = tmp_path / "new_dir"
    with pytest.raises(KeyboardInterrupt):
        media.write_outputs(images, out)
    assert not out.exists()
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("kept")
    with pytest.raises(KeyboardInterrupt):
        media.write_outputs(images, tmp_path / "mine")
    assert sorted(p.name for p in (tmp_path / "mine").iterdir()) == ["notes.txt"]
