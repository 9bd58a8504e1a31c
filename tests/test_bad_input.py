"""No input can crash the tool, fool it or cost a file (issue 21).

Every case here ended in a traceback, a silently wrong result or a lost file
before; now each gets a one-line error (exit code 2 for bad input, 1 for a
failed write) or a warning, and leaves no temporary file behind. The fast
cases use a tiny hand-written stage (tests/tiny_stage.py) and the packaged
BVH clips; the few that need the data set are marked by conftest.
"""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from tests.tiny_stage import ITEM_FACES, ITEM_POINTS, TINY_MAP, TINY_USDA, write_tiny, write_tiny_map
from wearfit_usd.cli import main
from wearfit_usd.errors import BVHError, GeometryError, NonFiniteError, OutputError, USDInputError
from wearfit_usd.io.bvh import read_bvh
from wearfit_usd.io.usd import read_character

REPO = Path(__file__).resolve().parents[1]
WALK = REPO / "wearfit_usd" / "motions" / "walk.bvh"

MINI_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT Head
    {
      OFFSET 0 60 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 0 10 0
      }
    }
  }
  JOINT LeftUpLeg
  {
    OFFSET 10 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -90 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 90 0 0 0 0 0 0 0 0 0 0 0 0 0
1 90 0 0 0 0 0 0 0 0 0 0 10 0 0
"""


def _bvh(tmp_path, text=MINI_BVH, name="clip.bvh") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _tiny_args(folder) -> list:
    """animate's options for the tiny stage: its 2-joint skeleton has no legs
    or arms to pair by role, so the user's joint map pairs it with the clip
    and the dressing's body fit is a similarity (--no-pose)."""
    return ["--map", write_tiny_map(folder), "--no-pose"]


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    return rc, capsys.readouterr().err


def _leftovers(folder: Path) -> list[str]:
    """Hidden temporary files/folders a writer left in ``folder``."""
    return sorted(p.name for p in Path(folder).iterdir() if p.name.startswith("."))


# --------------------------------------------------------------------------
# BVH: tracebacks

@pytest.mark.parametrize("frame_time", ["5e-324", "1e300"])
def test_bvh_frame_time_extremes_are_bvh_errors(tmp_path, frame_time):
    p = _bvh(tmp_path, MINI_BVH.replace("Frame Time: 0.0333333", f"Frame Time: {frame_time}"))
    with pytest.raises(BVHError) as e:
        read_bvh(p)
    assert e.value.line == 32 and "frame time" in str(e.value)


def test_bvh_denormal_end_site_offset(tmp_path):
    # a flat skeleton whose whole height is one denormal: the unit detection
    # took log(0) ("math domain error")
    text = MINI_BVH
    for old in ("OFFSET 0 10 0\n    CHANNELS", "OFFSET 0 60 0", "OFFSET 0 10 0\n      }", "OFFSET 0 -90 0"):
        text = text.replace(old, old.replace("10", "0").replace("60", "0").replace("-90", "0"), 1)
    text = text.replace("OFFSET 0 0 0\n      }", "OFFSET 0 5e-324 0\n      }", 1)
    m = read_bvh(_bvh(tmp_path, text))
    assert m.scale == 1.0 and "assumed" in m.units


def test_bvh_deep_hierarchy_parses_without_recursion(tmp_path):
    depth = 5000  # far past Python's recursion limit (the parser recursed per level)
    lines = ["HIERARCHY", "ROOT j0", "{", "OFFSET 0 0 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
    for i in range(1, depth):
        lines += [f"JOINT j{i}", "{", "OFFSET 0 0.01 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
    lines += ["End Site", "{", "OFFSET 0 0.01 0", "}"] + ["}"] * depth
    lines += ["MOTION", "Frames: 1", "Frame Time: 0.04", " ".join(["0"] * (3 * depth))]
    m = read_bvh(_bvh(tmp_path, "\n".join(lines) + "\n"))
    assert m.n_joints == depth and m.parents[-1] == depth - 2
    pos = m.global_transforms([0])[0, :, 3, :3]
    assert np.isfinite(pos).all()


def test_bvh_extreme_offset_names_joint_and_line(tmp_path):
    p = _bvh(tmp_path, MINI_BVH.replace("OFFSET 0 60 0", "OFFSET 0 1e308 0"))
    with pytest.raises(BVHError) as e:
        read_bvh(p)
    assert e.value.line == 12 and "Head" in str(e.value)


def test_bvh_extreme_positions_and_angles_name_frame_joint_line(tmp_path):
    p = _bvh(tmp_path, MINI_BVH.replace("1 90 0 0 0 0", "1 1e200 0 0 0 0"))
    with pytest.raises(BVHError) as e:
        read_bvh(p)
    assert e.value.line == 34 and "frame 1" in str(e.value) and "Hips" in str(e.value)
    p = _bvh(tmp_path, MINI_BVH.replace("0 0 10 0 0\n", "0 0 1e200 0 0\n"))
    with pytest.raises(BVHError) as e:
        read_bvh(p)
    assert "LeftUpLeg" in str(e.value) and "Zrotation" in str(e.value)


# --------------------------------------------------------------------------
# BVH: memory and silent wrong results in retargeting

def test_long_frame_time_is_bounded_before_allocating(tmp_path):
    from wearfit_usd.motion.retarget import retarget
    target = read_character(write_tiny(tmp_path / "t.usda"))
    m = read_bvh(_bvh(tmp_path, MINI_BVH.replace("Frame Time: 0.0333333", "Frame Time: 86400")))
    with pytest.raises(OutputError) as e:
        retarget(m, target.skeleton, fps=30.0, max_frames=100_000)
    assert "2592001 frames" in str(e.value) and "--max-frames" in str(e.value)


def test_non_finite_retarget_names_frame_and_joint(tmp_path):
    from wearfit_usd.motion.retarget import retarget
    target = read_character(write_tiny(tmp_path / "t.usda"))
    m = read_bvh(_bvh(tmp_path))
    m.values[1, 3] = np.nan  # past the reader's checks (e.g. from an API user)
    with pytest.raises(NonFiniteError) as e:
        retarget(m, target.skeleton, fps=None, mapping=json.loads(TINY_MAP))
    assert "clip frame 1, joint Hips" in str(e.value)
    # the target side: world transforms checked before they are written
    from wearfit_usd.motion.retarget import check_finite_transforms
    world = np.broadcast_to(np.eye(4), (3, 2, 4, 4)).copy()
    check_finite_transforms(world, np.arange(3.0), ["hips", "spine"], "c.bvh")
    world[2, 1, 3, 0] = np.inf
    with pytest.raises(NonFiniteError, match="output frame 2 .clip frame 2., joint spine"):
        check_finite_transforms(world, np.arange(3.0), ["hips", "spine"], "c.bvh")
    world[2, 1] = 0.0
    with pytest.raises(NonFiniteError, match="singular"):
        check_finite_transforms(world, np.arange(3.0), ["hips", "spine"], "c.bvh")


def test_animate_non_finite_points_name_the_frame():
    from wearfit_usd.animate.try_on import check_finite_points

    class RT:
        source_frames = np.array([3.0, 4.5])
    pts = np.zeros((5, 3))
    check_finite_points(pts, 0, RT, "clip.bvh")
    pts[2, 1] = np.inf
    with pytest.raises(NonFiniteError) as e:
        check_finite_points(pts, 1, RT, "clip.bvh")
    assert "item point 2 at output frame 1 (clip frame 4.5)" in str(e.value)


# --------------------------------------------------------------------------
# USD: tracebacks and silent wrong results

def test_usd_item_without_faces(tmp_path):
    p = write_tiny(tmp_path / "s.usda", ITEM_FACES,
                   "int[] faceVertexCounts = []\n        int[] faceVertexIndices = []")
    with pytest.raises(GeometryError, match="Scarf has no faces"):
        read_character(p)


def test_usd_skeleton_child_before_parent(tmp_path):
    p = write_tiny(tmp_path / "s.usda", '["hips", "hips/spine"]', '["hips/spine", "hips"]')
    with pytest.raises(USDInputError, match="every joint must come after its parent"):
        read_character(p)


def test_usd_nan_bind_transform(tmp_path):
    p = write_tiny(tmp_path / "s.usda", "(0, 1.5, 0, 1) )]", "(0, nan, 0, 1) )]")
    with pytest.raises(USDInputError, match="bindTransforms of joint hips/spine is NaN"):
        read_character(p)


def test_usd_singular_bind_transform(tmp_path):
    p = write_tiny(tmp_path / "s.usda", "(1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 1.5, 0, 1)",
                   "(0, 0, 0, 0), (0, 0, 0, 0), (0, 0, 0, 0), (0, 1.5, 0, 1)")
    with pytest.raises(USDInputError, match="singular"):
        read_character(p)


def test_usd_negative_face_vertex_count(tmp_path):
    p = write_tiny(tmp_path / "s.usda", ITEM_FACES,
                   "int[] faceVertexCounts = [5, -1]\n        int[] faceVertexIndices = [0, 1, 2, 3]")
    with pytest.raises(GeometryError, match="faceVertexCounts holds -1 at face 1"):
        read_character(p)


def test_usd_negative_meters_per_unit(tmp_path):
    p = write_tiny(tmp_path / "s.usda", "metersPerUnit = 1", "metersPerUnit = -1")
    with pytest.raises(USDInputError, match="metersPerUnit must be a positive number"):
        read_character(p)


def test_usd_item_with_all_points_equal(tmp_path):
    p = write_tiny(tmp_path / "s.usda", ITEM_POINTS, "[(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)]")
    with pytest.raises(GeometryError, match="all 4 points are equal"):
        read_character(p)


def test_usd_three_vertex_body(tmp_path):
    text = TINY_USDA.split('        def Mesh "Body"')[0] + textwrap.dedent('''\
        def Mesh "Body" (
            prepend apiSchemas = ["SkelBindingAPI"]
        )
        {
            int[] faceVertexCounts = [3]
            int[] faceVertexIndices = [0, 1, 2]
            point3f[] points = [(-0.2, 0, 0.1), (0.2, 0, 0.1), (-0.2, 2, 0.1)]
            int[] primvars:skel:jointIndices = [0, 0, 1] (
                elementSize = 1
                interpolation = "vertex"
            )
            float[] primvars:skel:jointWeights = [1, 1, 1] (
                elementSize = 1
                interpolation = "vertex"
            )
            rel skel:skeleton = </Root/Character/Skeleton>
        }
    }
''') + '    def Mesh "Scarf"' + TINY_USDA.split('    def Mesh "Scarf"')[1]
    p = tmp_path / "s.usda"
    p.write_text(text)
    with pytest.raises(GeometryError, match="3 points .* flat or too small to be a body"):
        read_character(p)


def test_usd_units_only_in_sublayer_warn(tmp_path):
    (tmp_path / "units.usda").write_text('#usda 1.0\n(\n    metersPerUnit = 1\n    upAxis = "Z"\n)\n')
    p = write_tiny(tmp_path / "s.usda", '    metersPerUnit = 1\n    upAxis = "Y"\n',
                   "    subLayers = [@./units.usda@]\n")
    with pytest.warns(UserWarning, match=r"sets no upAxis or metersPerUnit \(its sublayers'.*"
                                         r"assuming upAxis Y and metersPerUnit 0.01"):
        c = read_character(p)
    assert c.meters_per_unit == 0.01


def test_usd_corrupt_crate_file(tmp_path, usd_dir):
    data = bytearray((usd_dir / "body_male_heavy.usdc").read_bytes())
    for i in range(880009, 880025):  # inside an LZ4-compressed block
        data[i] ^= 0xFF
    p = tmp_path / "corrupt.usdc"
    p.write_bytes(bytes(data))
    with pytest.raises(USDInputError, match="corrupt or truncated file.*LZ4"):
        read_character(p)


# --------------------------------------------------------------------------
# CLI arguments

@pytest.mark.parametrize("args, message", [
    (["--fps", "inf"], "--fps: must be a finite number"),
    (["--fps", "abc"], "--fps: expected a number"),
    (["--fps", "1e9"], "--fps: must be a finite number > 0 and <= 1000"),
    (["--k", "0"], "--k: must be between 1 and 64"),
    (["--k", "1000"], "--k: must be between 1 and 64"),
    (["--clip-frames", "-1"], "--clip-frames: must be >= 1"),
    (["--max-frames", "0"], "--max-frames: must be >= 1"),
])
def test_animate_bad_numbers_are_usage_errors(tmp_path, capsys, args, message):
    ref = write_tiny(tmp_path / "ref.usda")
    with pytest.raises(SystemExit) as e:
        main(["animate", str(ref), str(ref), str(WALK), "-o", str(tmp_path / "o.usda"), *args])
    assert e.value.code == 2
    assert message in capsys.readouterr().err


def test_animate_unknown_joint_in_map(tmp_path, capsys):
    ref = write_tiny(tmp_path / "ref.usda")
    jmap = tmp_path / "map.json"
    jmap.write_text('{"nope": "Hips"}')
    rc, err = _run(["animate", ref, ref, WALK, "-o", tmp_path / "o.usda", "--map", jmap], capsys)
    assert rc == 2 and "target joints not in the skeleton: ['nope']" in err
    jmap.write_text('{"hips": "Nope"}')
    rc, err = _run(["animate", ref, ref, WALK, "-o", tmp_path / "o.usda", "--map", jmap], capsys)
    assert rc == 2 and "source joints not in the motion: ['Nope']" in err


def test_animate_max_frames(tmp_path, capsys):
    ref = write_tiny(tmp_path / "ref.usda")
    rc, err = _run(["animate", ref, ref, WALK, "-o", tmp_path / "o.usda", "--max-frames", "10"], capsys)
    assert rc == 2 and "the shot would have 60 frames" in err and "--max-frames" in err
    assert not (tmp_path / "o.usda").exists() and _leftovers(tmp_path) == []


# --------------------------------------------------------------------------
# losing files

def test_output_equal_to_an_input_is_refused(tmp_path, capsys):
    ref = write_tiny(tmp_path / "ref.usda")
    tgt = write_tiny(tmp_path / "tgt.usda")
    clip = tmp_path / "walk.bvh"
    clip.write_bytes(WALK.read_bytes())
    before = {p: p.read_bytes() for p in (ref, tgt, clip)}
    for argv in (["animate", ref, tgt, clip, "-o", tgt],
                 ["animate", ref, tgt, clip, "-o", tmp_path / "sub" / ".." / "ref.usda"],
                 ["animate", ref, tgt, clip, "-o", tmp_path / "o.usda", "--report", clip],
                 ["animate", ref, tgt, clip, "-o", tmp_path / "o.usda", "--report", tmp_path / "o.usda"],
                 ["dress", ref, tgt, "-o", ref],
                 ["dress", ref, tgt, "-o", tmp_path / "o.usda", "--report", tgt],
                 ["fit", ref, tgt, "-o", tgt],
                 ["fit", ref, tgt, "-o", tmp_path / "o.usda", "--report", ref]):
        rc, err = _run(argv, capsys)
        assert rc == 2, argv
        assert "would overwrite the input" in err or "names the same file" in err, err
    assert all(p.read_bytes() == b for p, b in before.items())


def test_output_through_a_symlink_is_refused(tmp_path, capsys):
    ref = write_tiny(tmp_path / "ref.usda")
    link = tmp_path / "link.usda"
    link.symlink_to(ref)
    rc, err = _run(["dress", ref, ref, "-o", link], capsys)
    assert rc == 2 and "would overwrite the input" in err


@pytest.mark.parametrize("command", ["animate", "dress", "fit"])
def test_output_extension_checked_up_front(tmp_path, capsys, command):
    ref = write_tiny(tmp_path / "ref.usda")
    argv = [command, ref, ref] + ([WALK] if command == "animate" else []) + ["-o", tmp_path / "x.txt"]
    rc, err = _run(argv, capsys)
    assert rc == 2 and "must end in .usd, .usda or .usdc" in err


def test_report_written_atomically(tmp_path, capsys):
    ref = write_tiny(tmp_path / "ref.usda")
    rep = tmp_path / "rep.json"
    rc, _ = _run(["animate", ref, ref, WALK, *_tiny_args(tmp_path),
                    "-o", tmp_path / "o.usdc", "--report", rep, "-q"], capsys)
    assert rc == 0 and rep.read_text().startswith("{") and _leftovers(tmp_path) == []


def test_clips_folder_keeps_foreign_files(tmp_path, capsys):
    ref = write_tiny(tmp_path / "ref.usda")
    clips = tmp_path / "shot.clips"
    clips.mkdir()
    (clips / "notes.txt").write_text("mine")
    (clips / "items.0099.usdc").write_text("stale layer of an earlier, longer shot")
    rc, err = _run(["animate", ref, ref, WALK, *_tiny_args(tmp_path),
                    "-o", tmp_path / "shot.usda", "--clip-frames", "25", "-q"],
                   capsys)
    assert rc == 0, err
    assert sorted(p.name for p in clips.iterdir()) == ["items.0000.usdc", "items.0001.usdc",
                                                      "items.0002.usdc", "notes.txt"]
    assert (clips / "notes.txt").read_text() == "mine"
    assert "Unable to open clip layer" not in err and _leftovers(tmp_path) == []
    from pxr import Usd, UsdGeom
    stage = Usd.Stage.Open(str(tmp_path / "shot.usda"))
    pts = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Items/Scarf")).GetPointsAttr()
    assert len(pts.Get(59)) == 4 and pts.GetTimeSamples()[-1] == 59


def test_clip_folder_path_taken_by_a_file(tmp_path, capsys):
    ref = write_tiny(tmp_path / "ref.usda")
    (tmp_path / "shot.clips").write_text("a file")
    rc, err = _run(["animate", ref, ref, WALK, *_tiny_args(tmp_path),
                    "-o", tmp_path / "shot.usda", "--clip-frames", "25"], capsys)
    assert rc == 2 and "is not a folder" in err and _leftovers(tmp_path) == []


_SCRIPT_PRELUDE = """
import os, signal, sys
sys.path.insert(0, {repo!r})
from wearfit_usd.cli import main
"""


def _subprocess_cli(tmp_path, argv, preexec=None, timeout=120):
    script = _SCRIPT_PRELUDE.format(repo=str(REPO)) + f"sys.exit(main({[str(a) for a in argv]!r}))\n"
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=timeout, preexec_fn=preexec, cwd=tmp_path)


def test_full_disk_during_close_leaves_nothing(tmp_path):
    import resource

    def small_files():  # writes past 3 kB fail with EFBIG, as on a full disk
        resource.setrlimit(resource.RLIMIT_FSIZE, (3_000, resource.RLIM_INFINITY))
    ref = write_tiny(tmp_path / "ref.usda")
    for extra in ([], ["--clip-frames", "20"]):
        r = _subprocess_cli(tmp_path, ["animate", ref, ref, WALK, *_tiny_args(tmp_path),
                    "-o", tmp_path / "s.usdc", "-q", *extra],
                            preexec=small_files)
        assert r.returncode == 1, r.stderr
        assert "Traceback" not in r.stderr and "cannot write" in r.stderr
        assert _leftovers(tmp_path) == [] and not (tmp_path / "s.usdc").exists()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_signals_clean_up_like_ctrl_c(tmp_path, sig):
    """SIGTERM/SIGHUP mid-shot: exit 128+signal, no temporary file or clip folder."""
    ref = write_tiny(tmp_path / "ref.usda")
    script = _SCRIPT_PRELUDE.format(repo=str(REPO)) + textwrap.dedent(f"""
        from wearfit_usd.io import usd_shot
        orig = usd_shot.ShotWriter.write_frame
        def write_frame(self, frame, pts):
            if frame == 30:
                assert any(n.startswith('.') for n in os.listdir({str(tmp_path)!r}))
                os.kill(os.getpid(), {int(sig)})
            return orig(self, frame, pts)
        usd_shot.ShotWriter.write_frame = write_frame
        sys.exit(main({["animate", str(ref), str(ref), str(WALK), *[str(a) for a in _tiny_args(tmp_path)],
                        "-o", str(tmp_path / "s.usdc"),
                        "--clip-frames", "10", "-q"]!r}))
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 128 + sig, r.stderr
    assert "stopped by" in r.stderr and "Traceback" not in r.stderr
    assert _leftovers(tmp_path) == [] and not (tmp_path / "s.usdc").exists()
    assert not (tmp_path / "s.clips").exists()


# --------------------------------------------------------------------------
# noise

def test_warnings_print_as_wearfit_messages(tmp_path, capsys):
    (tmp_path / "units.usda").write_text('#usda 1.0\n(\n    metersPerUnit = 1\n    upAxis = "Y"\n)\n')
    p = write_tiny(tmp_path / "s.usda", '    metersPerUnit = 1\n    upAxis = "Y"\n',
                   "    subLayers = [@./units.usda@]\n")
    rc, err = _run(["inspect", p], capsys)
    assert rc == 0
    assert "wearfit inspect: warning: " in err and "UserWarning" not in err and ".py:" not in err


def test_progress_only_on_a_terminal(tmp_path, monkeypatch):
    """A log file gets no bar (tqdm drew one carriage-return redraw per update)."""
    from wearfit_usd import progress as prog
    monkeypatch.setattr(prog, "_LEVEL", 1)
    with open(tmp_path / "log.txt", "w") as fh:
        monkeypatch.setattr(sys, "stderr", fh)
        assert sum(prog.progress(range(100_000), total=100_000, desc="animate")) == 4_999_950_000
    assert (tmp_path / "log.txt").read_text() == ""
